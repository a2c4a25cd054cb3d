"""Where `semmap run` takes poses from (--poses), trajectory.txt, and the `track` / `eval-traj` commands."""

from __future__ import annotations

import json

import numpy as np
import pytest

from helpers import make_room_frames, room_label_set, run_cli
from semmap.io.trajectory import read_trajectory, write_trajectory
from semmap.io.tum_writer import write_tum_sequence
from semmap.types import Trajectory, make_pose


@pytest.fixture(scope="module")
def room(tmp_path_factory):
    root = tmp_path_factory.mktemp("room-poses")
    write_tum_sequence(root, make_room_frames(8), label_set=room_label_set())
    return root


def _shifted(traj: Trajectory) -> Trajectory:
    """The same trajectory in another world frame (a rigid change of coordinates)."""
    c, s = np.cos(0.3), np.sin(0.3)
    W = make_pose(np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]), [1.0, -2.0, 0.5])
    return Trajectory(traj.timestamps, np.array([W @ T for T in traj.poses]), traj.names)


@pytest.mark.slow
def test_run_with_a_trajectory_file_maps_and_scores_it(room, tmp_path):
    est = tmp_path / "est.txt"
    write_trajectory(est, _shifted(read_trajectory(room / "groundtruth.txt")))
    out = tmp_path / "out"
    r = run_cli("run", str(room), "--out", str(out), "--resolution", "0.1", "--poses", str(est))
    assert r.returncode == 0, r.stderr
    report = json.loads((out / "report.json").read_text())
    assert report["poses"] == str(est) and report["frames_used"] == 8
    assert report["trajectory_vs_ground_truth"]["ate_rmse_m"] < 1e-6  # same path up to the world frame
    used = read_trajectory(out / "trajectory.txt")
    np.testing.assert_allclose(used.poses, read_trajectory(est).poses, atol=1e-6)


@pytest.mark.slow
def test_bad_pose_source_is_one_clear_line(room, tmp_path):
    r = run_cli("run", str(room), "--out", str(tmp_path / "o"), "--poses", str(tmp_path / "missing.txt"))
    assert r.returncode == 1 and "missing.txt does not exist" in r.stderr and "Traceback" not in r.stderr
    bad = tmp_path / "bad.txt"
    bad.write_text("1.0 0 0 0 0 0 0 1\n0.5 0 0 0 0 0 0 1\n")
    r = run_cli("run", str(room), "--out", str(tmp_path / "o"), "--poses", str(bad))
    assert r.returncode == 1 and "bad.txt" in r.stderr and "Traceback" not in r.stderr


@pytest.mark.slow
def test_eval_traj_scores_a_file_against_a_dataset_or_a_file(room, tmp_path):
    est = tmp_path / "est.txt"
    write_trajectory(est, _shifted(read_trajectory(room / "groundtruth.txt")))
    for reference in (room, room / "groundtruth.txt"):
        r = run_cli("eval-traj", str(reference), str(est), "--plot", str(tmp_path / "plot.png"), "--json")
        assert r.returncode == 0, r.stderr
        scores = json.loads(r.stdout)
        assert scores["ate_rmse_m"] < 1e-6 and scores["matched"] == 8
    assert (tmp_path / "plot.png").stat().st_size > 1000


@pytest.mark.slow
def test_eval_traj_compares_several_estimates_against_two_references(room, tmp_path):
    gt = read_trajectory(room / "groundtruth.txt")
    a, b = tmp_path / "a" / "est.txt", tmp_path / "b" / "est.txt"
    write_trajectory(a, _shifted(gt))
    write_trajectory(b, gt)
    r = run_cli("eval-traj", str(room), str(a), str(b), "--pairwise", "--reference2", str(room / "groundtruth.txt"),
                "--rotation-frames", "2", "--plot-errors", str(tmp_path / "errors.png"), "--json")
    assert r.returncode == 0, r.stderr
    result = json.loads(r.stdout)
    assert set(result["estimates"]) == {"a/est", "b/est"}  # repeated stems named by their folder
    assert result["pairwise"][0]["ate_m"] < 1e-6
    assert result["reference2"]["reference"]["ate_rmse_m"] < 1e-9
    assert np.abs(result["rotation_disagreement_deg"]["matrix"]).max() < 1e-6
    assert (tmp_path / "errors.png").stat().st_size > 1000
