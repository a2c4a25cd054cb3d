"""The map in the browser (issue 48, item 3): report.html shows the map in 3D, offline, in class colours with a
legend that hides and shows each class, object boxes with their class and id, the camera path and a switch to the
observed colours; past a voxel budget a seeded sample is drawn and the page says what was left out; ``semmap view
MAP --html`` writes the same view for a map file. The page is opened in a real headless Chromium."""

from __future__ import annotations

import base64
import json
import re
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from browser import (
    canvas_shot,
    chromium,
    chromium_or_skip,
    colours_shown,
    console_errors,
    network_requests,
    open_page,
    wait_for,
)
from object_helpers import box_frames
from semmap.eval.report_md import MAP_VIEW_MARKER
from semmap.io.map_files import load_map
from semmap.io.tum_writer import write_tum_sequence
from semmap.labels import INDOOR_LABELS
from semmap.types import EMPTY_LABEL, LabelSet, MapCloud
from semmap.viz.web_view import VOXEL_BUDGET, box_edges, map_figure, view_html

CHAIR, TABLE = INDOOR_LABELS.id_of("chair"), INDOOR_LABELS.id_of("table")
BOXES = [(np.array([-0.2, -0.8, 0.0]), np.array([0.2, -0.4, 0.8])),
         (np.array([0.8, 0.1, 0.0]), np.array([1.2, 0.5, 0.8])),
         (np.array([0.2, 0.9, 0.0]), np.array([1.2, 1.5, 0.75]))]
#: Whether the trace of class arguments[0] is shown as arguments[1] says (true, or "legendonly" once hidden).
VISIBLE = ("const t = document.getElementById('semmap-map-view').data.find(t => (t.name || '').startsWith("
           "arguments[0] + ' (')); return (t.visible === undefined ? true : t.visible) === arguments[1];")
#: The demo's page must stay under this (issue 48).
MAX_PAGE_BYTES = 15 * 2**20


def _cli(*args: str):
    from semmap.cli import app

    return CliRunner().invoke(app, list(args))


@pytest.fixture(scope="module")
def run(tmp_path_factory) -> Path:
    """``semmap run`` on three boxes with oracle instances: a map with classes, objects and a camera path."""
    root = tmp_path_factory.mktemp("view") / "boxes"
    write_tum_sequence(root, box_frames(BOXES, [CHAIR, CHAIR, TABLE], 10), label_set=INDOOR_LABELS)
    out = tmp_path_factory.mktemp("view-run") / "out"
    result = _cli("run", str(root), "--out", str(out), "--resolution", "0.05", "--instances", "oracle",
                  "--instance-errors", "exact")
    assert result.exit_code == 0, result.output
    return out


def _traces(page: str) -> list[dict]:
    """The traces of the page's plotly view (the first argument after its div's id in ``Plotly.newPlot``)."""
    at = re.search(r'Plotly\.newPlot\(\s*"semmap-map-view",\s*', page).end()
    return json.JSONDecoder().raw_decode(page, at)[0]


def _floats(spec: dict) -> np.ndarray:
    """The values of a plotly typed array (``{"dtype": "f4", "bdata": base64}``)."""
    assert spec["dtype"] == "f4"
    return np.frombuffer(base64.b64decode(spec["bdata"]), "<f4")


def _palette(names) -> dict[str, tuple[int, int, int]]:
    return {n: tuple(int(c) for c in INDOOR_LABELS.colors[INDOOR_LABELS.id_of(n)]) for n in names}


@pytest.mark.slow
def test_report_holds_the_map_in_3d_with_classes_objects_and_camera_path(run):
    page = (run / "report.html").read_text()
    md = (run / "report.md").read_text()
    assert "## The map in 3D" in md and MAP_VIEW_MARKER in md and MAP_VIEW_MARKER not in page
    assert "<script src=" not in page.split('<div class="map-view">', 1)[1]  # plotly inlined, nothing fetched
    figure = _traces(page)
    names = [t.get("name", "") for t in figure]
    report = json.loads((run / "report.json").read_text())
    for cls, voxels in report["voxels_per_class"].items():
        assert f"{cls} ({voxels:,})" in names, (cls, names)  # one legend entry per class, with its voxels
    objects = json.loads((run / "objects.json").read_text())["objects"]
    assert f"objects ({len(objects)})" in names and f"camera path ({report['frames_used']} poses)" in names
    labels = next(t["text"] for t in figure if t.get("mode") == "text")
    assert sorted(labels) == sorted(f"{o['id']} {o['class']}" for o in objects)


@pytest.mark.slow
def test_the_page_opens_offline_in_chromium_and_its_legend_and_rgb_switch_work(run):
    chromium_or_skip()
    from selenium.webdriver.common.by import By

    report = json.loads((run / "report.json").read_text())
    classes = _palette(report["voxels_per_class"])
    with chromium() as driver:
        open_page(driver, run / "report.html")
        assert console_errors(driver) == []
        assert network_requests(driver) == []  # everything the page needs is in it
        shot = canvas_shot(driver)
        assert shot.std() > 10, "the 3D view is blank"
        shown = colours_shown(shot, classes)
        assert len(shown) >= 2, shown
        # the legend: one click hides the class, another brings it back
        first = next(iter(report["voxels_per_class"]))
        item = next(e for e in driver.find_elements(By.CSS_SELECTOR, "div.js-plotly-plot g.legend g.traces")
                    if e.text.startswith(f"{first} ("))
        item.click()  # (plotly acts once the double-click delay has passed)
        wait_for(driver, VISIBLE, first, "legendonly")
        hidden = colours_shown(canvas_shot(driver), classes)
        assert first in shown and first not in hidden and hidden, (shown, hidden)
        item.click()
        wait_for(driver, VISIBLE, first, True)
        assert first in colours_shown(canvas_shot(driver), classes)
        # RGB: the observed colours replace the class colours
        next(e for e in driver.find_elements(By.CSS_SELECTOR, "div.js-plotly-plot g.updatemenu-button")
             if e.text == "RGB").click()
        wait_for(driver, "return document.getElementById('semmap-map-view').data[0].marker.color.length > 1")
        assert len(colours_shown(canvas_shot(driver), classes)) < len(shown)
        assert console_errors(driver) == [] and network_requests(driver) == []


@pytest.mark.slow
def test_view_html_writes_the_same_view_for_a_map_file(run, tmp_path):
    out = tmp_path / "map.html"
    result = _cli("view", str(run / "map.semmap"), "--html", str(out))
    assert result.exit_code == 0, result.output
    page = out.read_text()
    assert "<html" in page[:300] and "<script src=" not in page
    m = load_map(run / "map.semmap")
    said = "".join(result.output.split())  # the terminal may wrap the line anywhere
    assert f"{len(m.cloud()):,}voxels" in said and str(out) in said
    names = [t.get("name", "") for t in _traces(page)]
    assert names == [t.get("name", "") for t in _traces((run / "report.html").read_text())]  # the report's view
    report = json.loads((run / "report.json").read_text())
    assert all(any(n.startswith(f"{cls} (") for n in names) for cls in report["voxels_per_class"])
    assert any(n.startswith("camera path") for n in names) and any(n.startswith("objects (") for n in names)
    again = _cli("view", str(run / "map.semmap"), "--html", str(run / "map.semmap"))
    assert again.exit_code != 0 and "choose another --html" in str(again.exception)  # never over the map it reads
    both = _cli("view", str(run / "map.semmap"), "--html", str(out), "--save", str(tmp_path / "map.rrd"))
    assert both.exit_code != 0 and "give one of them" in str(both.exception)
    product = _cli("view", str(run / "objects.json"), "--html", str(tmp_path / "objects.html"))
    assert product.exit_code != 0 and "not the products" in str(product.exception)


def test_past_the_budget_a_seeded_sample_is_drawn_and_the_page_stays_small():
    n = 3 * VOXEL_BUDGET
    rng = np.random.default_rng(1)
    labels = rng.integers(1, 40, n).astype(np.uint16)
    labels[::50] = EMPTY_LABEL
    cloud = MapCloud(rng.uniform(-20, 20, (n, 3)), rng.integers(0, 256, (n, 3), dtype=np.uint8), labels,
                     np.ones(n, np.float32), 0.05)
    path = rng.uniform(-5, 5, (3000, 3))
    fig, shown = map_figure(cloud, LabelSet.generic(40), camera_positions=path)
    assert (shown.voxels, shown.drawn) == (n, VOXEL_BUDGET)
    assert f"{n - VOXEL_BUDGET:,} left out" in shown.note and shown.note in fig["layout"]["title"]["text"]
    assert sum(len(_floats(t["x"])) for t in fig["data"] if t.get("mode") == "markers") == VOXEL_BUDGET
    again, _ = map_figure(cloud, LabelSet.generic(40), camera_positions=path)
    assert again == fig  # the same sample every time
    assert len(view_html(fig).encode()) < MAX_PAGE_BYTES  # every voxel of the budget at its largest


def test_box_edges_trace_the_twelve_edges_of_an_oriented_box():
    a = np.radians(30)
    R = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    edges = box_edges([1.0, 2.0, 0.5], R, [2.0, 1.0, 1.0]).reshape(12, 3, 3)
    assert np.isnan(edges[:, 2]).all()
    lengths = sorted(np.linalg.norm(edges[:, 0] - edges[:, 1], axis=1).round(6))
    assert lengths == [1.0] * 8 + [2.0] * 4
    local = (edges[:, :2].reshape(-1, 3) - [1.0, 2.0, 0.5]) @ R  # back in the box's axes: the corners
    assert np.allclose(np.abs(local), [1.0, 0.5, 0.5])
