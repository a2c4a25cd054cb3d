"""The ``--help`` of every command, word for word as tests/data/cli_help.txt records it: the CLI's layout in modules
may change, what a user reads may not, unless the fixture is rewritten on purpose.

A change of a help text that is meant: ``.venv/bin/python tests/test_cli_help.py`` rewrites the fixture; commit it
with the change, so the diff shows what the user will read."""

from __future__ import annotations

import re
import sys
from pathlib import Path

import pytest
import typer
import typer.rich_utils
from typer.testing import CliRunner

FIXTURE = Path(__file__).parent / "data" / "cli_help.txt"
#: a wide, plain terminal: no wrapping that depends on the machine, no colour codes
ENV = {"COLUMNS": "200", "TERM": "dumb", "NO_COLOR": "1"}
#: the line before each help text in the fixture
HEADER = re.compile(r"^===== semmap ?(.*) --help =====\n", re.MULTILINE)


def command_paths() -> list[str]:
    """Every command as the words a user types after ``semmap`` ('' is ``semmap --help`` itself)."""
    from semmap.cli import app

    def walk(command, prefix: str) -> list[str]:
        found = [prefix]
        for name, sub in getattr(command, "commands", {}).items():
            found += walk(sub, f"{prefix} {name}".strip())
        return found

    return walk(typer.main.get_command(app), "")


def help_text(path: str) -> str:
    """``semmap PATH --help`` as a 200-column plain terminal shows it, each line's trailing blanks dropped."""
    from semmap.cli import app

    saved = typer.rich_utils.MAX_WIDTH, typer.rich_utils.FORCE_TERMINAL
    typer.rich_utils.MAX_WIDTH, typer.rich_utils.FORCE_TERMINAL = 200, False  # (TERMINAL_WIDTH, CI's FORCE_COLOR)
    try:
        result = CliRunner().invoke(app, [*path.split(), "--help"], env=ENV, prog_name="semmap")
    finally:
        typer.rich_utils.MAX_WIDTH, typer.rich_utils.FORCE_TERMINAL = saved
    assert result.exit_code == 0, result.output
    return "".join(line.rstrip() + "\n" for line in result.output.splitlines())  # (no trailing blanks to strip)


def recorded() -> dict[str, str]:
    """The fixture: command path -> its help text."""
    if not FIXTURE.is_file():
        return {}
    parts = HEADER.split(FIXTURE.read_text())[1:]  # [path, text, path, text, ...]
    return dict(zip(parts[::2], parts[1::2], strict=True))


def write_fixture() -> None:
    FIXTURE.write_text("".join(f"===== {f'semmap {path}'.strip()} --help =====\n{help_text(path)}"
                               for path in command_paths()))


def test_every_command_has_a_recorded_help() -> None:
    assert sorted(command_paths()) == sorted(recorded()), "a command was added or removed: rewrite the fixture " \
                                                          "(python tests/test_cli_help.py) and commit it"


@pytest.mark.slow
@pytest.mark.parametrize("path", sorted(recorded()))
def test_help_is_unchanged(path: str) -> None:
    assert help_text(path) == recorded()[path], (f"`semmap {path} --help` changed; if that is meant, rewrite "
                                                 "the fixture (python tests/test_cli_help.py) and commit it")


if __name__ == "__main__":
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))
    write_fixture()
    print(f"wrote {FIXTURE}")
