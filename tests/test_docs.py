"""The docs match the code: every package and top-level module is named in "Layout", and the README stays short."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "src" / "semmap"
#: README.md's size limit in bytes: a user guide, not a results dump (numbers live in docs/BENCHMARKS.md).
README_MAX_BYTES = 20 * 1024
#: the most rows README's generated headline table may have
HEADLINE_MAX_ROWS = 10


def section(path: Path, heading: str) -> str:
    """The text of the ``## heading`` section of a Markdown file (up to the next ``## ``), or '' if absent."""
    text = path.read_text(encoding="utf-8")
    match = re.search(rf"^## {re.escape(heading)}\s*$(.*?)(?=^## |\Z)", text, flags=re.MULTILINE | re.DOTALL)
    return match.group(1) if match else ""


def named(name: str, text: str) -> bool:
    """Whether ``name`` (``batch.py``, ``maps/``, ``perception/instances/``) appears as a whole path in ``text``."""
    return re.search(rf"(?<![\w/.]){re.escape(name)}(?![\w])", text) is not None


def packages(top_only: bool) -> list[str]:
    """Packages under src/semmap as ``maps/`` or ``perception/instances/`` (only the first level if ``top_only``)."""
    found = sorted(p.parent.relative_to(SRC).as_posix() + "/" for p in SRC.rglob("__init__.py") if p.parent != SRC)
    return [p for p in found if not top_only or p.count("/") == 1]


def top_modules() -> list[str]:
    """Top-level modules of semmap as file names (``batch.py``), the package's ``__init__.py`` aside."""
    return sorted(p.name for p in SRC.glob("*.py") if p.name != "__init__.py")


def test_the_inventory_is_not_empty() -> None:
    assert "maps/" in packages(top_only=True) and "perception/instances/" in packages(top_only=False)
    assert "runner.py" in top_modules() and "__init__.py" not in top_modules()


def test_named_matches_whole_paths_only() -> None:
    assert named("io/", "`io/` files") and not named("io/", "`fusion/io/` files")
    assert named("keys.py", "keys.py: voxel keys") and not named("keys.py", "maps/_keys.py")


@pytest.mark.parametrize("name", packages(top_only=False) + top_modules())
def test_design_layout_names_every_package_and_module(name: str) -> None:
    layout = section(ROOT / "docs" / "DESIGN.md", "Layout")
    assert layout, "docs/DESIGN.md has no '## Layout' section"
    assert named(name, layout), f"docs/DESIGN.md 'Layout' does not name src/semmap/{name}"


@pytest.mark.parametrize("name", packages(top_only=True) + top_modules())
def test_readme_layout_names_every_package_and_module(name: str) -> None:
    layout = section(ROOT / "README.md", "Layout")
    assert layout, "README.md has no '## Layout' section"
    assert named(name, layout), f"README.md 'Layout' does not name src/semmap/{name}"


def test_readme_is_at_most_20_kb() -> None:
    size = (ROOT / "README.md").stat().st_size
    assert size <= README_MAX_BYTES, f"README.md is {size:,} B, over {README_MAX_BYTES:,} B: move detail to docs/"


def test_readme_headline_table_is_generated_and_short() -> None:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    start, end = "<!-- headline:start", "<!-- headline:end -->"
    assert start in text and end in text, "README.md lacks the headline markers benchmarks/update_docs.py writes"
    block = text.split(start, 1)[1].split(end, 1)[0]
    rows = [line for line in block.splitlines() if line.startswith("| ") and not line.startswith("| measured")]
    assert 0 < len(rows) <= HEADLINE_MAX_ROWS
