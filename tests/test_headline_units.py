"""Numbers that cannot be misread (issue 48, item 2): wherever the map and its network are compared (the demo's
summary, report.md, the README's headline), the first comparison is at the same pixels, and a voxel mIoU never
shares a row with a pixel MIoU; the README names the realism preset the demo really renders with."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
from typer.testing import CliRunner

from semmap.eval.headline import NETWORK_ALONE, SAME_PIXELS, VOXELS_3D, accuracy_rows

ROOT = Path(__file__).resolve().parents[1]
_IOU = re.compile(r"\bm?iou\b", re.IGNORECASE)
_VOXEL = re.compile(r"\b3D\b|voxel", re.IGNORECASE)
_PIXEL = re.compile(r"\b2D\b|pixel|single[- ]frame", re.IGNORECASE)


def mixes_units(row: str) -> bool:
    """Whether a row states an IoU and speaks of both voxels and pixels (two units in one comparison)."""
    return bool(_IOU.search(row) and _VOXEL.search(row) and _PIXEL.search(row))


def test_the_unit_check_catches_the_old_headline_row():
    old = ("| `make demo`: 300 simulated frames, shipped fcn network | 3D mIoU of the map 0.497; 139 ms per frame in "
           "all | 2D mIoU of the single frames 0.543 | `update_docs.py` |")
    assert mixes_units(old)
    assert not mixes_units("| Label fusion | top-3 OctoMap mIoU 0.605 at 30 B/voxel | Bayes 0.640 at 249 B/voxel |")


@pytest.fixture(scope="module")
def demo(tmp_path_factory) -> tuple[Path, str]:
    """A short oracle demo through the CLI, its summary printed wide enough that no row wraps."""
    from semmap.cli import app

    out = tmp_path_factory.mktemp("units") / "demo"
    result = CliRunner().invoke(app, ["demo", "--out", str(out), "--frames", "20", "--semantics", "oracle"],
                                env={"COLUMNS": "400"})
    assert result.exit_code == 0, result.output
    return out, result.output


def _summary_rows(output: str) -> list[str]:
    """The rows of the summary table rich printed (``│ key │ value │``)."""
    return [line for line in output.splitlines() if line.count("│") >= 3]


@pytest.mark.slow
def test_demo_summary_leads_with_the_same_pixels_and_keeps_units_apart(demo):
    out, output = demo
    rows = _summary_rows(output)
    named = [r for r in rows if _IOU.search(r)]
    assert named, output
    assert SAME_PIXELS in named[0], named  # the first comparison is at the same pixels
    assert any(VOXELS_3D in r and "geometric precision" in r and "coverage" in r for r in named), named
    assert not [r for r in rows if mixes_units(r)]
    report = json.loads((out / "report.json").read_text())
    assert [name for name, _ in accuracy_rows(report)] == [SAME_PIXELS, VOXELS_3D, NETWORK_ALONE]
    assert f"{report['pixel_miou_map']:.3f}" in named[0] and f"{report['pixel_miou_network']:.3f}" in named[0]


@pytest.mark.slow
def test_report_md_leads_with_the_same_pixels_and_no_table_row_mixes_units(demo):
    out, _ = demo
    md = (out / "report.md").read_text()
    headings = [line for line in md.splitlines() if line.startswith("## ")]
    assert headings[0].lower() == f"## {SAME_PIXELS}", headings
    assert f"## {VOXELS_3D}" in headings
    assert md.index("At the same pixels") < md.index(VOXELS_3D)
    assert not [row for row in md.splitlines() if row.startswith("|") and mixes_units(row)]
    report = json.loads((out / "report.json").read_text())
    assert f"Realism: `{report['realism']}`" in md  # the preset the frames were rendered with, named


def _headline_rows() -> list[str]:
    text = (ROOT / "README.md").read_text()
    block = text.split("<!-- headline:start", 1)[1].split("<!-- headline:end -->", 1)[0]
    return [line for line in block.splitlines() if line.startswith("| ") and not line.startswith("| measured")]


def test_readme_headline_keeps_units_apart_and_leads_with_the_same_pixels():
    rows = _headline_rows()
    assert not [r for r in rows if mixes_units(r)]
    demo_rows = [r for r in rows if "demo" in r and _IOU.search(r)]
    assert len(demo_rows) == 2 and SAME_PIXELS in demo_rows[0] and VOXELS_3D in demo_rows[1], demo_rows
    assert "geometric precision" in demo_rows[1] and "coverage" in demo_rows[1]


@pytest.mark.slow
def test_readme_names_the_realism_preset_the_demo_renders_with(demo):
    out, _ = demo
    realism = json.loads((out / "report.json").read_text())["realism"]
    text = re.sub(r"\s+", " ", (ROOT / "README.md").read_text())
    paragraph = text.split("## The demo", 1)[1].split("|", 1)[0]
    assert f"realism `{realism}`" in paragraph, paragraph
    headline = [r for r in _headline_rows() if SAME_PIXELS in r]
    assert headline and f"realism `{realism}`" in headline[0]
