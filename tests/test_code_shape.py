"""The shape of the code a newcomer reads: no function (or method) over 80 lines outside numba kernels, the
papers' algorithms written as one piece and the CLI's option declarations, the run's frame loop class
(``Pipeline``) at most 250 lines, and no module of the command line (one per command family) over 400 lines."""

from __future__ import annotations

import ast
import functools
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src" / "semmap"
MAX_FUNCTION_LINES = 80
MAX_PIPELINE_LINES = 250
MAX_CLI_MODULE_LINES = 400
#: Functions allowed to be longer, with the reason: the papers' algorithms kept as one piece, step for step.
ALGORITHMS = {
    "fusion/topk_bayes.py:fuse_sets": "Algorithm 1 of the semantic OctoMap paper, line for line",
}


def _decorators(node: ast.FunctionDef) -> list[str]:
    return [ast.unparse(d) for d in node.decorator_list]


@functools.cache
def _commands() -> frozenset[str]:
    """``cli/mapping.py:run``: the function of every command of ``semmap`` (wired in ``semmap/cli/__init__.py``)."""
    import typer

    from semmap.cli import app

    def callbacks(group) -> list:
        return [getattr(c.callback, "__wrapped__", c.callback) for c in group.commands.values()
                if c.callback is not None] + [cb for sub in group.commands.values()
                                               if hasattr(sub, "commands") for cb in callbacks(sub)]

    return frozenset(f"{f.__module__.removeprefix('semmap.').replace('.', '/')}.py:{f.__name__}"
                     for f in callbacks(typer.main.get_command(app)))


def _exempt(path: Path, node: ast.FunctionDef) -> bool:
    """numba kernels (``@nb.njit``...) and typer commands (their option declarations) may be longer."""
    decos = " ".join(_decorators(node))
    where = f"{path.relative_to(SRC).as_posix()}:{node.name}"
    return "njit" in decos or where in _commands() or where in ALGORITHMS


def _long_functions() -> list[str]:
    found = []
    for path in sorted(SRC.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
                lines = node.end_lineno - node.lineno + 1
                if lines > MAX_FUNCTION_LINES and not _exempt(path, node):
                    found.append(f"{path.relative_to(SRC)}:{node.lineno} {node.name} ({lines} lines)")
    return found


@pytest.mark.slow
def test_no_function_is_over_80_lines_outside_kernels_algorithms_and_cli_options():
    assert _long_functions() == []


def test_the_frame_loop_class_stays_small():
    tree = ast.parse((SRC / "pipeline.py").read_text())
    cls = next(n for n in tree.body if isinstance(n, ast.ClassDef) and n.name == "Pipeline")
    assert cls.end_lineno - cls.lineno + 1 <= MAX_PIPELINE_LINES


def test_the_commands_are_found() -> None:
    assert {"cli/mapping.py:run", "cli/products.py:export_grid_command"} <= _commands()


def test_no_module_of_the_command_line_is_over_400_lines() -> None:
    """One module per command family (docs/DESIGN.md): a family that grows past 400 lines splits in two."""
    sizes = {p.relative_to(SRC).as_posix(): len(p.read_text().splitlines()) for p in (SRC / "cli").glob("*.py")}
    assert len(sizes) > 5 and {name: n for name, n in sizes.items() if n > MAX_CLI_MODULE_LINES} == {}
