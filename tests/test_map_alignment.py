"""Scores in the right frame: a map built from a tracker's poses lies in the tracker's frame; it is moved onto the
ground truth by the ATE's SE(3) alignment before any 3D score and in the trajectory plot, and the report says how."""

from __future__ import annotations

import json
import logging
from types import SimpleNamespace

import numpy as np
import pytest

from helpers import make_room_frames, room_label_set
from semmap.config import RunConfig
from semmap.eval.report_md import render_report_md
from semmap.eval.report_plots import _trajectory_in_one_frame
from semmap.eval.run_report import RunScorer
from semmap.eval.trajectory import alignment_to_ground_truth
from semmap.runner import run_config
from semmap.sim.export import simulate_sequence
from semmap.types import MapCloud, Trajectory, invert_pose, make_pose, transform_points


def _rotation(axis: str, degrees: float) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    return Rotation.from_euler(axis, degrees, degrees=True).as_matrix()


def _room_ground_truth(n: int = 20) -> Trajectory:
    frames = make_room_frames(n)
    return Trajectory(np.array([f.timestamp for f in frames]), np.stack([f.T_world_cam for f in frames]),
                      tuple(f.name for f in frames))


# ------------------------------------------------------------------------------------------------ the transform
def test_alignment_is_the_transform_from_the_tracker_frame_onto_the_ground_truth():
    gt = _room_ground_truth()
    T_gt_est = make_pose(_rotation("zyx", [40, -10, 25]), [1.5, -0.3, 2.0])
    est = Trajectory(gt.timestamps, invert_pose(T_gt_est) @ gt.poses, gt.names)  # the same path, another frame
    T, how = alignment_to_ground_truth(gt, est)
    np.testing.assert_allclose(T, T_gt_est, atol=1e-9)
    assert how == {"method": "se3 umeyama on the trajectory", "frames": len(gt)}


def test_a_camera_that_stays_put_is_aligned_by_its_first_pose():
    gt = _room_ground_truth(5)
    still = Trajectory(gt.timestamps, np.repeat(gt.poses[:1], len(gt), axis=0), gt.names)
    est = Trajectory(gt.timestamps, np.repeat(np.eye(4)[None], len(gt), axis=0), gt.names)
    T, how = alignment_to_ground_truth(still, est)
    np.testing.assert_allclose(T, gt.poses[0], atol=1e-12)
    assert how["method"] == "se3 offset of the first matched pose" and how["frames"] == 1 and "why" in how


class _Poses:
    """The two trajectories a run's pose source reports (``FramePoses``'s interface for the scorer)."""

    def __init__(self, source: str, used: Trajectory, gt: Trajectory) -> None:
        self.source, self._used, self._gt = source, used, gt

    def used_trajectory(self) -> Trajectory:
        return self._used

    def ground_truth(self) -> Trajectory:
        return self._gt


def test_scorer_aligns_estimated_poses_only_and_refuses_to_score_in_an_unknown_frame(caplog):
    gt = _room_ground_truth()
    truth = lambda res: (np.zeros((0, 3), np.int64), np.zeros(0, np.int64))  # noqa: E731
    same = RunScorer(truth, 0.1)
    same.align_to(_Poses("gt", gt, gt))
    assert same.T_gt_map is None and same.alignment is None  # ground-truth poses: scored as they are

    T_gt_est = make_pose(_rotation("z", 30), [1.0, 2.0, 0.0])
    moved = RunScorer(truth, 0.1)
    moved.align_to(_Poses("slam", Trajectory(gt.timestamps, invert_pose(T_gt_est) @ gt.poses, gt.names), gt))
    np.testing.assert_allclose(moved.T_gt_map, T_gt_est, atol=1e-9)
    assert moved.alignment["frames"] == len(gt)
    np.testing.assert_allclose(moved.alignment["T_gt_map"], T_gt_est, atol=1e-8)

    lost = RunScorer(truth, 0.1)
    with caplog.at_level(logging.WARNING, logger="semmap"):
        lost.align_to(_Poses("slam", gt, Trajectory(gt.timestamps[:0], gt.poses[:0], ())))
    assert "not scored in 3D" in caplog.text and lost.alignment["method"] == "none"
    assert lost.map_3d(SimpleNamespace(label_set=room_label_set())) == {}  # never scored in the wrong frame


def test_trajectory_plot_draws_the_estimate_and_its_map_in_the_ground_truth_frame():
    gt = _room_ground_truth()
    T_gt_est = make_pose(_rotation("x", 70), [0.5, 0.0, 1.0])
    used = Trajectory(gt.timestamps, invert_pose(T_gt_est) @ gt.poses, gt.names)
    centers = np.array([[0.0, 0.0, 0.0], [1.0, 2.0, 3.0]])
    cloud = MapCloud(centers, np.zeros((2, 3), np.uint8), np.zeros(2, np.uint16), np.zeros(2, np.float32), 0.1)
    report = {"poses": "slam", "map_alignment": {"method": "se3 umeyama on the trajectory", "frames": len(gt),
                                                  "T_gt_map": T_gt_est.tolist()}}
    args = _trajectory_in_one_frame(report, used, gt, cloud)
    np.testing.assert_allclose(args["used"].poses, gt.poses, atol=1e-9)
    np.testing.assert_allclose(args["cloud"].centers, transform_points(T_gt_est, centers))
    assert args["ground_truth"] is gt and "aligned" in args["label"]
    # no alignment known: the ground truth is left out rather than drawn in another frame
    assert _trajectory_in_one_frame({"poses": "slam"}, used, gt, cloud)["ground_truth"] is None


# ------------------------------------------------------------------------------------------------ a real tracker
@pytest.fixture(scope="module")
def mapped(tmp_path_factory):
    """A 30-frame simulated sequence mapped with ground-truth poses and with dense odometry (its own frame)."""
    root = tmp_path_factory.mktemp("frame")
    seq = simulate_sequence(root / "seq", kind="office", size="small", frames=30)
    reports = {}
    for source in ("gt", "odometry"):
        config = RunConfig.model_validate({
            "input": {"dataset": str(seq)}, "poses": {"source": source}, "semantics": {"source": "oracle"},
            "mapping": {"resolution": 0.05, "pixel_stride": 2},
            "output": {"out": str(root / source), "preview": False}})
        run_config(config)
        reports[source] = json.loads((root / source / "report.json").read_text())
    return reports


@pytest.mark.slow
def test_a_tracked_map_scores_within_two_points_of_the_ground_truth_posed_map(mapped):
    gt, est = mapped["gt"], mapped["odometry"]
    assert "map_alignment" not in gt
    a = est["map_alignment"]
    assert a["method"] == "se3 umeyama on the trajectory" and a["frames"] == 30
    T = np.asarray(a["T_gt_map"])
    assert np.linalg.norm(T[:3, 3]) > 0.5  # the tracker's frame is not the world's: the scores needed the move
    assert abs(est["miou_3d"] - gt["miou_3d"]) <= 0.02, (est["miou_3d"], gt["miou_3d"])
    assert est["geometric_precision_3d"] >= 0.98
    md = render_report_md(est)
    assert "3D scores and the trajectory plot move it onto the ground truth" in md
