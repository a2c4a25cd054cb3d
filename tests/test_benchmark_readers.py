"""ScanNet and Replica readers (issue 36), tested on sequences the simulator writes in those layouts: the same
frames as its own TUM export, labels mapped to NYU-40 for ScanNet, and one clear line for every broken file."""

from __future__ import annotations

import struct

import numpy as np
import pytest

from semmap.datasets import detect_format, open_dataset
from semmap.datasets.replica import ReplicaDataset
from semmap.datasets.scannet import ScanNetDataset
from semmap.errors import DatasetError
from semmap.labels import INDOOR_LABELS, NYU40_NAMES, simulator_to_nyu40
from semmap.sim.export import simulate_sequence

FRAMES = 3
SIZE = (80, 60)


@pytest.fixture(scope="module")
def exports(tmp_path_factory) -> dict:
    root = tmp_path_factory.mktemp("layouts")
    return {layout: simulate_sequence(root / layout, frames=FRAMES, image_size=SIZE, layout=layout, scene_seed=3)
            for layout in ("tum", "scannet", "replica")}


def frames_of(path) -> list:
    return list(open_dataset(path))


@pytest.mark.slow
def test_formats_are_detected(exports):
    assert detect_format(exports["scannet"]) == "scannet" and detect_format(exports["replica"]) == "replica"


def test_scannet_scan_reads_back_the_simulated_frames(exports):
    ref, got = frames_of(exports["tum"]), frames_of(exports["scannet"])
    assert len(got) == FRAMES
    ds = ScanNetDataset(exports["scannet"])
    assert ds.label_set.names == NYU40_NAMES and ds.intrinsics == ref[0].intrinsics
    to_nyu = simulator_to_nyu40()
    for a, b in zip(ref, got, strict=True):
        assert np.allclose(a.T_world_cam, b.T_world_cam, atol=1e-6)
        assert np.abs(a.depth - b.depth).max() <= 0.0006  # millimetres against 1/5000 m
        assert np.array_equal(to_nyu[a.labels], b.labels)
        assert np.array_equal(np.clip(a.instances, 0, 255), b.instances)
        assert np.abs(a.rgb.astype(int) - b.rgb).mean() < 4  # JPEG


def test_replica_scene_reads_back_the_simulated_frames(exports):
    ref, got = frames_of(exports["tum"]), frames_of(exports["replica"])
    ds = ReplicaDataset(exports["replica"])
    assert ds.label_set.names == INDOOR_LABELS.names and ds.intrinsics == ref[0].intrinsics
    for a, b in zip(ref, got, strict=True):
        assert np.allclose(a.T_world_cam, b.T_world_cam, atol=1e-6)
        assert np.abs(a.depth - b.depth).max() <= 0.0003
        assert np.array_equal(a.labels, b.labels)


def test_broken_sens_files_name_the_file(exports, tmp_path):
    good = next(exports["scannet"].glob("*.sens")).read_bytes()
    cases = {"truncated": good[: len(good) // 2], "header": good[:30], "version": struct.pack("<I", 3) + good[4:],
             "count": good}
    count_at = good.index(b"semmap simulator") + len(b"semmap simulator") + 64 * 4 + 2 * 4 + 4 * 4 + 4
    cases["count"] = good[:count_at] + struct.pack("<Q", 10**12) + good[count_at + 8:]
    for name, data in cases.items():
        scan = tmp_path / name
        scan.mkdir()
        (scan / "x.sens").write_bytes(data)
        with pytest.raises(DatasetError, match=r"x\.sens"):
            ScanNetDataset(scan)


def test_invalid_scannet_pose_is_skipped(exports, tmp_path, caplog):
    data = bytearray(next(exports["scannet"].glob("*.sens")).read_bytes())
    first = data.index(b"semmap simulator") + len(b"semmap simulator") + 64 * 4 + 2 * 4 + 4 * 4 + 4 + 8
    data[first:first + 4] = struct.pack("<f", float("-inf"))  # ScanNet's mark of lost tracking
    scan = tmp_path / "lost"
    scan.mkdir()
    (scan / "x.sens").write_bytes(bytes(data))
    ds = ScanNetDataset(scan)
    assert len(list(ds)) == FRAMES - 1 and "tracking lost" in ds.skipped[0].reason


def test_scannet_without_label_map_warns(exports, tmp_path, caplog):
    scan = tmp_path / "nomap"
    scan.mkdir()
    (scan / "x.sens").write_bytes(next(exports["scannet"].glob("*.sens")).read_bytes())
    (scan / "label-filt").mkdir()
    assert ScanNetDataset(scan).label_set is None
    assert "scannetv2-labels.combined.tsv" in caplog.text


def test_replica_trajectory_errors_name_the_line(exports, tmp_path):
    import shutil

    scene = tmp_path / "office0"
    shutil.copytree(exports["replica"], scene)
    (scene / "traj.txt").write_text("1 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1\n1 2 3\n")
    with pytest.raises(DatasetError, match=r"traj\.txt: line 2 has 3 numbers"):
        ReplicaDataset(scene)


def test_frequency_weighted_miou_and_mean_accuracy():
    from semmap.eval.semantic import confusion, scores

    gt = np.array([1, 1, 1, 1, 2, 2, 0, 3])
    pred = np.array([1, 1, 1, 2, 2, 2, 1, 1])
    s = scores(confusion(pred, gt, 4))  # class 0 ignored; class 3 present once, never right
    iou = {1: 3 / 5, 2: 2 / 3, 3: 0.0}
    assert s.fw_miou == pytest.approx((4 * iou[1] + 2 * iou[2] + 1 * iou[3]) / 7)
    assert s.mean_class_accuracy == pytest.approx((3 / 4 + 2 / 2 + 0) / 3)
