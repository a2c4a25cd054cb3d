"""Hostile and odd input: every case ends with one clear line (or a correct result with a warning), no traceback
from inside numpy, numba, zipfile or rosbags, bounded memory and no hang."""

from __future__ import annotations

import json
import logging
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from helpers import make_room_frames, room_label_set, run_cli, write_7scenes_sequence, write_png
from hostile import MAX_RSS_MB
from semmap import pipeline
from semmap.config import InputConfig, MappingConfig, OutputConfig, RunConfig
from semmap.datasets import open_dataset
from semmap.errors import ConfigError, DatasetError
from semmap.eval.segmentation import evaluate_label_folders
from semmap.io.tum_writer import write_tum_sequence
from semmap.pipeline import Pipeline

HOSTILE = Path(__file__).with_name("hostile.py")


@pytest.fixture(scope="module")
def room(tmp_path_factory):
    root = tmp_path_factory.mktemp("room-hostile")
    write_tum_sequence(root, make_room_frames(5), label_set=room_label_set())
    return root


@pytest.fixture(scope="module")
def hostile(tmp_path_factory):
    """The hostile files, read one after another in a fresh process: (folder, outcomes and peak memory)."""
    folder = tmp_path_factory.mktemp("hostile")
    r = subprocess.run([sys.executable, str(HOSTILE), str(folder)], capture_output=True, text=True, timeout=180)
    assert r.returncode == 0, r.stderr
    return folder, json.loads(r.stdout.strip().splitlines()[-1])


@pytest.mark.slow
def test_every_hostile_file_is_one_clear_error_in_bounded_memory(hostile):
    folder, result = hostile
    assert len(result["outcomes"]) >= 20
    for case, outcome in result["outcomes"].items():
        assert outcome.startswith("SemmapError: ") and str(folder) in outcome, (case, outcome)
    assert result["peak_rss_mb"] < MAX_RSS_MB


def test_cli_reports_a_device_in_one_line(hostile):
    folder, _ = hostile
    r = run_cli("info", str(folder / "zero.ot"))
    assert r.returncode == 1 and r.stderr.count("\n") == 1 and r.stderr.startswith("semmap: error: "), r.stderr
    assert "is a device" in r.stderr


def _config(room: Path, out: Path, **mapping) -> RunConfig:
    return RunConfig(input=InputConfig(dataset=room), mapping=MappingConfig(resolution=0.2, **mapping),
                     output=OutputConfig(out=out, plots=False, preview=False))


def test_out_that_is_a_file_is_refused_before_mapping(room, tmp_path, monkeypatch):
    out = tmp_path / "taken"
    out.write_text("not a folder")
    opened = []
    monkeypatch.setattr(pipeline, "open_dataset_of", lambda *a, **k: opened.append(1))
    with pytest.raises(ConfigError, match="is a file; give a folder \\(nothing was mapped\\)"):
        Pipeline(_config(room, out)).run()
    with pytest.raises(ConfigError, match=r"lies below .*taken, which is a file"):
        Pipeline(_config(room, out / "sub")).run()
    assert opened == []  # refused before the dataset was even opened


def test_frames_beyond_max_range_warn_that_they_added_nothing(room, tmp_path, caplog):
    with caplog.at_level(logging.WARNING, logger="semmap"):
        Pipeline(_config(room, tmp_path / "o", max_range=0.0)).run()
    assert "5 frames added nothing to the map" in caplog.text and "--max-range 0.0" in caplog.text


def test_poses_a_million_metres_away_warn_why_the_map_is_empty(room, tmp_path, caplog):
    from semmap.config import PosesConfig
    from semmap.io.trajectory import read_trajectory, write_trajectory
    from semmap.types import Trajectory

    gt = read_trajectory(room / "groundtruth.txt")
    far = gt.poses.copy()
    far[:, :3, 3] += 1e6
    write_trajectory(tmp_path / "far.txt", Trajectory(gt.timestamps, far))
    config = _config(room, tmp_path / "o").model_copy(update={"poses": PosesConfig(source=str(tmp_path / "far.txt"))})
    with caplog.at_level(logging.WARNING, logger="semmap"), pytest.raises(ConfigError) as info:
        Pipeline(config).run()  # each frame is skipped naming it, then the run stops in one line
    assert "frame 0.000000 has no pose (its camera lies 1,000,0" in caplog.text
    assert ("no frame could be mapped (0 unreadable, 5 without pose) (5 cameras lie beyond the ±6,554 m the maps can "
            "hold at --resolution 0.2 m") in str(info.value)


@pytest.mark.slow
def test_opencv_says_nothing_of_its_own_about_a_corrupt_image(room, tmp_path):
    seq = tmp_path / "seq"
    shutil.copytree(room, seq)
    victim = sorted((seq / "rgb").iterdir())[1]
    victim.write_bytes(victim.read_bytes()[:60])
    r = run_cli("run", str(seq), "--out", str(tmp_path / "o"), "--resolution", "0.2")
    assert r.returncode == 0, r.stderr
    assert victim.name in r.stderr and "WARN:" not in r.stderr and "libpng" not in r.stderr


def test_missing_seven_scenes_intrinsics_warn_which_are_assumed(tmp_path, caplog):
    write_7scenes_sequence(tmp_path / "s", make_room_frames(2), write_intrinsics=False)
    with caplog.at_level(logging.WARNING, logger="semmap"):
        open_dataset(tmp_path / "s")
    assert "no camera-intrinsics.txt; assuming the 7-Scenes Kinect's depth camera: fx = 585" in caplog.text


def test_duplicate_timestamps_warn(room, tmp_path, caplog):
    seq = tmp_path / "dup"
    shutil.copytree(room, seq)
    lines = (seq / "rgb.txt").read_text().splitlines()
    (seq / "rgb.txt").write_text("\n".join([*lines, lines[-1]]) + "\n")
    with caplog.at_level(logging.WARNING, logger="semmap"):
        open_dataset(seq)
    assert "rgb.txt: 1 rows repeat an earlier timestamp" in caplog.text


@pytest.fixture
def label_folders(tmp_path):
    pred, gt = tmp_path / "pred", tmp_path / "gt"
    truth = np.zeros((4, 6), np.uint8)
    truth[:, 3:] = 1
    write_png(gt / "a.png", truth)
    write_png(pred / "a.png", truth)
    return pred, gt


def test_eval_seg_refuses_sizes_ids_and_class_counts_it_cannot_score(label_folders, caplog):
    pred, gt = label_folders
    with pytest.raises(ConfigError, match=r"--num-classes must be a whole number from 2 to 65,535"):
        evaluate_label_folders(pred, gt, 70000)
    write_png(pred / "a.png", np.full((4, 6), 7, np.uint8))
    with pytest.raises(DatasetError, match=r"a\.png: predicted class id 7 is not below --num-classes 2"):
        evaluate_label_folders(pred, gt, 2)
    write_png(pred / "a.png", np.zeros((2, 3), np.uint8))
    with pytest.raises(DatasetError, match="pass --resize"):
        evaluate_label_folders(pred, gt, 2)
    with caplog.at_level(logging.WARNING, logger="semmap"):
        assert evaluate_label_folders(pred, gt, 2, resize=True).images == 1
    assert "resized (nearest neighbour)" in caplog.text


def test_eval_seg_on_all_ignored_ground_truth_gives_null_not_nan(label_folders):
    pred, gt = label_folders
    write_png(gt / "a.png", np.full((4, 6), 255, np.uint8))
    scores = evaluate_label_folders(pred, gt, 2).to_dict()
    text = json.dumps(scores, allow_nan=False)  # strict JSON, as eval-seg --out writes it
    assert scores["miou"] is None and scores["mpa"] is None and "NaN" not in text


def test_large_class_counts_are_scored_sparsely(label_folders):
    pred, gt = label_folders
    r = evaluate_label_folders(pred, gt, 60000)
    assert r.scores.miou == 1.0 and r.pairs.tolist() == [[0, 0, 12], [1, 1, 12]]
    assert r.to_dict()["confusion"] == {"nonzero": [[0, 0, 12], [1, 1, 12]]}
