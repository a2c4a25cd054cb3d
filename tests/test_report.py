"""report.md gains plots (trajectory over the map, IoU per class, storage, time per stage) and report.html carries
the same report with every picture embedded, readable without the run folder."""

from __future__ import annotations

import json
import re

import cv2
import numpy as np
import pytest

from helpers import make_room_frames, room_label_set
from semmap.config import InputConfig, MappingConfig, OutputConfig, RunConfig
from semmap.eval.report_html import render_report_html
from semmap.eval.report_plots import PLOT_FILES, storage_sizes, write_report_plots
from semmap.io.tum_writer import write_tum_sequence
from semmap.pipeline import Pipeline
from semmap.types import Trajectory


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    root = tmp_path_factory.mktemp("room-report")
    write_tum_sequence(root, make_room_frames(6), label_set=room_label_set())
    out = tmp_path_factory.mktemp("room-report-out") / "out"  # (--out never inside its input)
    Pipeline(RunConfig(input=InputConfig(dataset=root), mapping=MappingConfig(resolution=0.1),
                       output=OutputConfig(out=out))).run()
    return out


def _picture(path) -> np.ndarray:
    image = cv2.imread(str(path))
    assert image is not None, path
    return image


@pytest.mark.slow
def test_run_writes_plots_that_report_md_shows(run):
    md = (run / "report.md").read_text()
    for section in ("trajectory", "storage", "timings"):
        assert f"]({PLOT_FILES[section]})" in md
        image = _picture(run / PLOT_FILES[section])
        assert image.shape[0] > 200 and image.shape[1] > 500 and image.std() > 10  # drawn, not blank
    assert PLOT_FILES["iou"] not in md  # no ground-truth classes scored in this run: no IoU plot


def test_report_html_is_self_contained(run):
    page = (run / "report.html").read_text()
    sources = re.findall(r'<img src="([^"]+)"', page)
    assert len(sources) == 4 and all(s.startswith("data:image/png;base64,") for s in sources)  # 3 plots + preview
    assert "<table>" in page and "<h2>Storage</h2>" in page
    report = json.loads((run / "report.json").read_text())
    assert f"{report['frames_used']}" in page


def test_iou_plot_and_trajectory_against_ground_truth(tmp_path):
    frames = make_room_frames(20)
    gt = Trajectory(np.array([f.timestamp for f in frames]), np.stack([f.T_world_cam for f in frames]))
    poses = gt.poses.copy()
    poses[:, 0, 3] += 0.05
    report = {"poses": "slam", "trajectory_vs_ground_truth": {"ate_rmse_m": 0.0, "rpe_trans_m": 0.0, "matched": 20},
              "per_class_iou_3d": {"wall": 0.8, "floor": 0.6}, "oracle_per_class_iou_2d": {"wall": 0.7, "chair": 0.2},
              "dense_point_cloud_bytes": 10**8, "bytes_on_disk": {"map.ot": 10**5, "preview.png": 10}}
    plots = write_report_plots(tmp_path, report, used=Trajectory(gt.timestamps, poses), ground_truth=gt)
    assert set(plots) == {"trajectory", "iou", "storage"}
    for name in plots.values():
        assert _picture(tmp_path / name).std() > 10
    assert storage_sizes(report) == {"dense point cloud (PLY)": 10**8, "map.ot": 10**5}  # pictures are not storage


def test_html_links_pictures_it_cannot_embed(tmp_path):
    page = render_report_html("# t\n\n![a](missing.png)\n", tmp_path)
    assert '<img src="missing.png"' in page
