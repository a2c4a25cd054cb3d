"""End to end: `semmap run` on sequences written by the tests (and on 7-Scenes when present)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyoctomap
import pytest

from helpers import make_room_frames, room_label_set, run_cli, run_cli_process
from semmap.config import InputConfig, MappingConfig, OutputConfig, RunConfig
from semmap.io.tum_writer import write_tum_sequence
from semmap.pipeline import Pipeline

REPORT_KEYS = {"frames_used", "frames_skipped", "occupied_leaves", "free_leaves", "bytes_in_memory",
               "bytes_on_disk", "ms_per_frame"}


@pytest.fixture(scope="module")
def room_sequence(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("room")
    write_tum_sequence(root, make_room_frames(12), label_set=room_label_set())
    return root


def _occupied_leaves(tree) -> int:
    return sum(1 for leaf in tree.begin_leafs() if tree.isNodeOccupied(leaf))


@pytest.mark.slow
def test_run_writes_every_output_and_octomap_agrees_with_the_report(room_sequence, tmp_path):
    """Through a new ``python -m semmap.cli`` process, as a user runs it (the other CLI tests run in-process)."""
    out = tmp_path / "out"
    r = run_cli_process("run", str(room_sequence), "--out", str(out), "--resolution", "0.1")
    assert r.returncode == 0, r.stderr
    for name in ("map.ot", "map.bt", "map.semmap", "preview.png", "report.json", "config.json"):
        assert (out / name).stat().st_size > 0, name
    report = json.loads((out / "report.json").read_text())
    assert set(report) >= REPORT_KEYS
    assert report["frames_used"] == 12 and report["frames_skipped"] == 0
    assert set(report["bytes_on_disk"]) >= {"map.ot", "map.bt", "map.semmap"}
    assert {"backproject", "raycast", "occupancy", "total"} <= set(report["ms_per_frame"])
    ot = pyoctomap.ColorOcTree(0.1).read(str(out / "map.ot"))
    bt = pyoctomap.OcTree(0.1)
    assert bt.readBinary(str(out / "map.bt"))
    assert _occupied_leaves(ot) == report["occupied_leaves"] == _occupied_leaves(bt)
    # walls are coloured by their class in the .ot
    palette = {tuple(c) for c in room_label_set().colors.tolist()[1:]}
    colours = {tuple(leaf.getColor()) for leaf in ot.begin_leafs() if ot.isNodeOccupied(leaf)}
    assert colours <= palette and len(colours) >= 4


def test_labelled_room_is_mapped_with_the_right_classes(room_sequence, tmp_path):
    config = RunConfig(input=InputConfig(dataset=room_sequence), mapping=MappingConfig(resolution=0.1),
                       output=OutputConfig(out=tmp_path / "o"))
    result = Pipeline(config).run()
    vox = result.octomap.voxels()
    floor = vox.centers[:, 2] < 0.05
    assert floor.sum() > 20
    assert np.mean(vox.labels[floor, 0] == 5) > 0.9  # label 5 = floor (z- face)
    assert result.report["occupied_voxels"] == result.octomap.num_occupied


@pytest.mark.slow
def test_missing_and_corrupt_frames_are_skipped_named_and_counted(room_sequence, tmp_path):
    import shutil

    seq = tmp_path / "seq"
    shutil.copytree(room_sequence, seq)
    depth_files = sorted((seq / "depth").iterdir())
    depth_files[3].unlink()
    rgb_files = sorted((seq / "rgb").iterdir())
    rgb_files[5].write_bytes(rgb_files[5].read_bytes()[:40])
    r = run_cli("run", str(seq), "--out", str(tmp_path / "out"), "--resolution", "0.1")
    assert r.returncode == 0, r.stderr
    assert depth_files[3].name in r.stderr and rgb_files[5].name in r.stderr
    report = json.loads((tmp_path / "out" / "report.json").read_text())
    assert report["frames_used"] == 10 and report["frames_skipped"] == 2
    assert {Path(s["path"]).name for s in report["skipped"]} == {depth_files[3].name, rgb_files[5].name}


@pytest.mark.slow
def test_bad_inputs_give_one_clear_line_and_exit_code_1(room_sequence, tmp_path):
    r = run_cli("run", str(tmp_path / "nowhere"), "--out", str(tmp_path / "o"))
    assert r.returncode == 1 and r.stderr.strip().startswith("semmap: error:") and "nowhere" in r.stderr
    assert "Traceback" not in r.stderr
    r = run_cli("run", str(room_sequence), "--out", str(tmp_path / "o"), "--resolution", "-1")
    assert r.returncode == 1 and "resolution" in r.stderr and "Traceback" not in r.stderr
    import shutil

    seq = tmp_path / "nanpose"
    shutil.copytree(room_sequence, seq)
    gt = (seq / "groundtruth.txt").read_text().splitlines()
    i = next(i for i, line in enumerate(gt) if not line.startswith("#"))
    parts = gt[i].split()
    parts[1] = "nan"
    gt[i] = " ".join(parts)
    (seq / "groundtruth.txt").write_text("\n".join(gt) + "\n")
    r = run_cli("run", str(seq), "--out", str(tmp_path / "o2"))  # one skip policy: that frame is left out
    assert r.returncode == 0 and "groundtruth.txt" in r.stderr and "Traceback" not in r.stderr
    assert json.loads((tmp_path / "o2" / "report.json").read_text())["frames_skipped"] == 1
    r = run_cli("run", str(seq), "--out", str(tmp_path / "o3"), "--strict")
    assert r.returncode == 1 and "groundtruth.txt" in r.stderr and "Traceback" not in r.stderr


@pytest.mark.slow
def test_info_describes_written_maps(room_sequence, tmp_path):
    out = tmp_path / "out"
    assert run_cli("run", str(room_sequence), "--out", str(out), "--resolution", "0.2").returncode == 0
    report = json.loads((out / "report.json").read_text())
    for name in ("map.ot", "map.bt"):
        d = json.loads(run_cli("info", str(out / name)).stdout)
        assert d["occupied_leaves"] == report["occupied_leaves"]
    d = json.loads(run_cli("info", str(out / "map.semmap")).stdout)
    assert d["occupied"] == report["occupied_voxels"]


@pytest.mark.slow
def test_seven_scenes_frames_map_end_to_end(seven_scenes, tmp_path):
    config = RunConfig(input=InputConfig(dataset=seven_scenes, max_frames=3, stride=20),
                       mapping=MappingConfig(resolution=0.05), output=OutputConfig(out=tmp_path / "o"))
    result = Pipeline(config).run()
    assert result.report["frames_used"] == 3
    assert result.report["occupied_voxels"] > 5000
    assert result.report["points_integrated"] > 3 * 250_000


@pytest.mark.slow
def test_simulate_then_run_evaluates_against_the_scenes_ground_truth(tmp_path):
    seq, out = tmp_path / "seq", tmp_path / "out"
    r = run_cli("simulate", "--out", str(seq), "--frames", "12", "--kind", "kitchen", "--size", "small")
    assert r.returncode == 0, r.stderr
    assert {"rgb.txt", "depth.txt", "groundtruth.txt", "labelset.json", "objects.json", "scene.json"} <= {
        p.name for p in seq.iterdir()}
    r = run_cli("run", str(seq), "--out", str(out), "--resolution", "0.1")
    assert r.returncode == 0, r.stderr
    report = json.loads((out / "report.json").read_text())
    assert report["frames_used"] == 12 and report["label_set"] == 30
    assert report["miou_3d"] > 0.6, "ground-truth labels from the folder give an accurate map"
