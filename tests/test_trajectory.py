"""Trajectories: SE(3) algebra, TUM trajectory files, pose lookup by time, ATE/RPE with evo, dense odometry."""

from __future__ import annotations

import logging

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from semmap.errors import ConfigError, FormatError
from semmap.eval.trajectory import (
    ate_without_alignment,
    compare_trajectories,
    evaluate_trajectory,
    on_common_frames,
    plot_position_errors,
    plot_trajectories,
)
from semmap.io.trajectory import (
    clean_poses,
    pose_at,
    read_trajectory,
    read_tum,
    write_trajectory,
)
from semmap.poses.file import GroundTruthRecorder, TrajectoryPoses, trajectory_of_dataset
from semmap.poses.track import make_tracker
from semmap.types import (
    Frame,
    Trajectory,
    interpolate_pose,
    invert_pose,
    make_pose,
    orthonormalize,
    quat_xyzw_to_rot,
    rot_to_quat_xyzw,
)

unit = st.floats(-1.0, 1.0, allow_nan=False)
quats = st.tuples(unit, unit, unit, unit).filter(lambda q: np.linalg.norm(q) > 0.1)
vectors = st.tuples(*(st.floats(-10.0, 10.0, allow_nan=False),) * 3)


def _pose(q, t) -> np.ndarray:
    return make_pose(quat_xyzw_to_rot(q), t)


def _random_rotation(rng: np.random.Generator) -> np.ndarray:
    return quat_xyzw_to_rot(rng.normal(size=4))


def _trajectory(n: int = 60, seed: int = 0) -> Trajectory:
    """A smooth, non-degenerate camera path (a wobbly circle with turning camera), 30 Hz."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / 30.0
    poses = []
    for k, s in enumerate(t):
        yaw = 0.8 * s + 0.05 * np.sin(3 * s + k * 0.01)
        R = quat_xyzw_to_rot([0.1 * np.sin(s), np.sin(yaw / 2), 0.05, np.cos(yaw / 2)])
        pos = [np.cos(s), np.sin(s), 0.3 * np.sin(2 * s)] + 0.001 * rng.normal(size=3)
        poses.append(make_pose(R, pos))
    return Trajectory(t, np.array(poses), tuple(f"f{k}" for k in range(n)))


# --------------------------------------------------------------------------------------------------
# SE(3) algebra
# --------------------------------------------------------------------------------------------------
@settings(max_examples=60, deadline=None)
@given(quats, vectors, quats, vectors)
def test_invert_compose_identity(q1, t1, q2, t2):
    A, B = _pose(q1, t1), _pose(q2, t2)
    assert np.allclose(A @ invert_pose(A), np.eye(4), atol=1e-9)
    assert np.allclose(invert_pose(A @ B), invert_pose(B) @ invert_pose(A), atol=1e-9)


@settings(max_examples=60, deadline=None)
@given(quats)
def test_quaternion_round_trip(q):
    q = np.asarray(q) / np.linalg.norm(q)
    back = rot_to_quat_xyzw(quat_xyzw_to_rot(q))
    assert min(np.abs(back - q).max(), np.abs(back + q).max()) < 1e-9


@settings(max_examples=60, deadline=None)
@given(quats, vectors, quats, vectors, st.floats(0.0, 1.0))
def test_interpolation_endpoints_and_rigidity(q1, t1, q2, t2, alpha):
    A, B = _pose(q1, t1), _pose(q2, t2)
    assert np.allclose(interpolate_pose(A, B, 0.0), A, atol=1e-9)
    assert np.allclose(interpolate_pose(A, B, 1.0), B, atol=1e-9)
    M = interpolate_pose(A, B, alpha)
    assert np.allclose(M[:3, :3] @ M[:3, :3].T, np.eye(3), atol=1e-9)
    assert np.allclose(M[:3, 3], (1 - alpha) * A[:3, 3] + alpha * B[:3, 3])


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 2**32 - 1), st.floats(1e-6, 5e-3))
def test_orthonormalize_gives_nearest_rotation(seed, eps):
    rng = np.random.default_rng(seed)
    R = _random_rotation(rng)
    noisy = R + eps * rng.normal(size=(3, 3))
    fixed = orthonormalize(noisy)
    assert np.allclose(fixed @ fixed.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(fixed) > 0
    assert np.abs(fixed - R).max() < 10 * eps


# --------------------------------------------------------------------------------------------------
# TUM trajectory files
# --------------------------------------------------------------------------------------------------
def test_tum_round_trip(tmp_path):
    traj = _trajectory(40)
    path = write_trajectory(tmp_path / "sub" / "traj.txt", traj)
    back = read_trajectory(path)
    assert np.allclose(back.timestamps, traj.timestamps, atol=1e-9)
    assert np.allclose(back.poses, traj.poses, atol=1e-7)
    assert path.read_text().startswith("#")
    assert not list(path.parent.glob(".*.tmp"))


@pytest.mark.parametrize(("text", "problem"), [
    ("", "no poses"),
    ("# only a comment\n\n", "no poses"),
    ("0.0 1 2 3 0 0 0 1\n1.0 1 2 3 0 0 1\n", ":2: expected 8 values"),
    ("0.0 1 2 x 0 0 0 1\n", ":1: 'x' is not a number"),
    ("0.0 1 2 3 0 0 0 1\n1.0 1 2 3 0 0 0 1\n0.5 1 2 3 0 0 0 1\n", ":3: timestamp"),
    ("0.0 1 2 3 0 0 0 1\n0.0 1 2 3 0 0 0 1\n", ":2: timestamp"),
    ("0.0 1 2 3 0 0 0 0\n", ":1: quaternion is zero"),
    ("0.0 1 2 3 0 0 0 2\n", ":1: quaternion norm"),
    ("0.0 1 2 3 0 0 0 nan\n", ":1: pose has non-finite"),
    ("nan 1 2 3 0 0 0 1\n", ":1: timestamp 'nan' is not finite"),
])
def test_bad_trajectory_files(tmp_path, text, problem):
    path = tmp_path / "bad.txt"
    path.write_text(text)
    with pytest.raises(FormatError, match=r"bad\.txt") as info:
        read_trajectory(path, strict=True)
    assert problem in str(info.value)


def test_missing_trajectory_file(tmp_path):
    with pytest.raises(FormatError, match="does not exist"):
        read_trajectory(tmp_path / "nope.txt")


def test_rotation_far_from_orthonormal_is_an_error():
    poses = _trajectory(5).poses.copy()
    poses[3, :3, :3] *= 1.05
    with pytest.raises(FormatError, match=r"my-gt: pose 3 .*not orthonormal"):
        clean_poses(poses, "my-gt")
    gt = Trajectory(np.arange(5.0), poses)
    with pytest.raises(FormatError, match="not orthonormal"):
        evaluate_trajectory(gt, _trajectory(5))


# --------------------------------------------------------------------------------------------------
# ATE / RPE
# --------------------------------------------------------------------------------------------------
def test_ate_of_rigid_perturbation_is_zero_after_alignment():
    gt = _trajectory(60)
    rng = np.random.default_rng(3)
    G = make_pose(_random_rotation(rng), rng.normal(size=3))
    est = Trajectory(gt.timestamps, np.array([G @ T for T in gt.poses]))
    result = evaluate_trajectory(gt, est)
    assert result["matched"] == 60
    assert result["ate_rmse_m"] < 1e-6
    assert result["rpe_trans_m"] < 1e-6
    assert result["rpe_rot_deg"] < 1e-4
    assert ate_without_alignment(gt, est)["ate_rmse_m"] > 0.1


def test_sim3_scale_reveals_a_trajectory_too_long_by_a_known_factor():
    """A trajectory 4 % too long (depth calibrated 4 % off) keeps an SE(3) ATE, a Sim(3) ATE of zero, and the
    scale that maps it back onto the ground truth; a rigidly moved copy has scale 1."""
    gt = _trajectory(60)
    rng = np.random.default_rng(5)
    G = make_pose(_random_rotation(rng), rng.normal(size=3))
    longer = gt.poses.copy()
    longer[:, :3, 3] *= 1.04
    result = evaluate_trajectory(gt, Trajectory(gt.timestamps, np.array([G @ T for T in longer])))
    assert result["sim3_scale"] == pytest.approx(1 / 1.04, rel=1e-6)
    assert result["ate_sim3_rmse_m"] < 1e-6 < 1e-3 < result["ate_rmse_m"]
    rigid = evaluate_trajectory(gt, Trajectory(gt.timestamps, np.array([G @ T for T in gt.poses])))
    assert rigid["sim3_scale"] == pytest.approx(1.0, rel=1e-9)


def test_ate_without_alignment_equals_translation_offset():
    gt = _trajectory(30)
    offset = np.array([0.03, -0.04, 0.0])  # 5 cm
    est = Trajectory(gt.timestamps + 0.004, gt.poses.copy())
    est.poses[:, :3, 3] += offset
    raw = ate_without_alignment(gt, est)
    assert raw["ate_rmse_m"] == pytest.approx(0.05, abs=1e-9)
    assert raw["ate_max_m"] == pytest.approx(0.05, abs=1e-9)
    assert evaluate_trajectory(gt, est)["ate_rmse_m"] < 1e-9


def test_rpe_of_identical_trajectories_is_zero():
    gt = _trajectory(30)
    result = evaluate_trajectory(gt, gt)
    assert result["rpe_trans_m"] == pytest.approx(0.0, abs=1e-12)
    assert result["rpe_rot_deg"] == pytest.approx(0.0, abs=1e-5)
    assert result["ate_rmse_m"] == pytest.approx(0.0, abs=1e-9)


def test_slightly_non_orthonormal_ground_truth_is_accepted():
    gt = _trajectory(30)
    poses = gt.poses.copy()
    poses[:, :3, :3] += 3e-4 * np.random.default_rng(1).uniform(-1, 1, size=(30, 3, 3))
    noisy_gt = Trajectory(gt.timestamps, poses)
    assert evaluate_trajectory(noisy_gt, gt)["ate_rmse_m"] < 1e-3


def test_too_few_matched_poses_is_a_clear_error():
    gt = _trajectory(30)
    late = Trajectory(gt.timestamps + 100.0, gt.poses)
    with pytest.raises(ConfigError, match="only 0 estimated poses match"):
        evaluate_trajectory(gt, late)


def test_plot_trajectories_writes_png(tmp_path):
    gt = _trajectory(40)
    est = Trajectory(gt.timestamps, gt.poses.copy())
    est.poses[:, :3, 3] += 0.01 * np.sin(np.arange(40))[:, None]
    path = plot_trajectories(tmp_path / "plot.png", gt, {"wobbly": est}, title="test")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_plot_position_errors_writes_png_and_refuses_other_frames(tmp_path):
    gt = _trajectory(40)
    est = Trajectory(gt.timestamps, gt.poses.copy())
    est.poses[:, :3, 3] *= 1.05
    path = plot_position_errors(tmp_path / "errors.png", gt, {"gt": gt, "scaled": est}, with_scale=True,
                                highlight="gt", title="test")
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    short = Trajectory(gt.timestamps[:20], gt.poses[:20])
    with pytest.raises(ConfigError, match="short: 20 poses, the reference has 40"):
        plot_position_errors(tmp_path / "bad.png", gt, {"short": short})


def _with_position_error(traj: Trajectory, error: np.ndarray) -> Trajectory:
    poses = traj.poses.copy()
    poses[:, :3, 3] += error
    return Trajectory(traj.timestamps, poses, traj.names)


def test_pairwise_comparison_finds_the_error_two_estimates_share():
    gt = _trajectory(120)
    rng = np.random.default_rng(4)
    common = 0.02 * np.stack([np.sin(np.arange(120) / 9), np.cos(np.arange(120) / 13), np.zeros(120)], axis=1)
    a = _with_position_error(gt, common + 0.005 * rng.normal(size=(120, 3)))
    b = _with_position_error(gt, common + 0.005 * rng.normal(size=(120, 3)))
    result = compare_trajectories(gt, {"a": a, "b": b}, pairwise=True)
    [pair] = result["pairwise"]
    ate_a = result["estimates"]["a"]["ate_rmse_m"]
    assert pair["between"] == ["a", "b"] and pair["ate_m"] < ate_a  # closer to each other than to the reference
    # the shared part is the common error as the alignment leaves it: far above the 5 mm own errors
    assert 0.01 < pair["shared_m"] <= ate_a and pair["correlation"] > 0.7
    unrelated = compare_trajectories(gt, {"a": _with_position_error(gt, 0.01 * rng.normal(size=(120, 3))),
                                          "b": _with_position_error(gt, 0.01 * rng.normal(size=(120, 3)))},
                                     pairwise=True)
    assert unrelated["pairwise"][0]["correlation"] < 0.2


def test_second_reference_and_rotation_disagreement_of_a_drifting_reference():
    gt = _trajectory(90)
    spin = np.array([quat_xyzw_to_rot([0, 0, np.sin(0.001 * k), np.cos(0.001 * k)]) for k in range(90)])
    drifting = gt.poses.copy()
    drifting[:, :3, :3] = spin @ gt.poses[:, :3, :3]  # heading drifts by 0.002 rad a frame
    ref2 = Trajectory(gt.timestamps, drifting, gt.names)
    est = Trajectory(gt.timestamps[::2], gt.poses[::2], gt.names[::2])  # every other frame only
    result = compare_trajectories(gt, {"est": est}, reference2=ref2, rotation_frames=5)
    assert result["estimates"]["est"]["ate_rmse_m"] < 1e-9
    assert set(result["reference2"]) == {"reference", "est"}
    rot = result["rotation_disagreement_deg"]
    assert rot["order"] == ["reference", "reference2", "est"] and rot["common_frames"] == 45
    matrix = np.array(rot["matrix"])
    assert matrix[0, 2] < 1e-6  # the estimate is the reference's own poses
    # five common frames are ten frames of the drift: 0.02 rad
    assert matrix[0, 1] == pytest.approx(np.degrees(0.02), rel=0.02)
    np.testing.assert_allclose(matrix, matrix.T, atol=1e-9)


def test_common_frames_keep_only_poses_every_trajectory_matches():
    gt = _trajectory(30)
    late = Trajectory(gt.timestamps[5:] + 0.005, gt.poses[5:], gt.names[5:])
    ref, common = on_common_frames(gt, {"late": late, "all": gt})
    assert len(ref) == 25 and ref.names[0] == "f5"
    np.testing.assert_allclose(common["late"].poses, gt.poses[5:])
    with pytest.raises(ConfigError, match="matched by every trajectory"):
        on_common_frames(gt, {"far": Trajectory(gt.timestamps + 5.0, gt.poses)})


# --------------------------------------------------------------------------------------------------
# Pose sources
# --------------------------------------------------------------------------------------------------
def test_file_poses_interpolate_between_two_poses(tmp_path):
    A = make_pose(np.eye(3), [0.0, 0.0, 0.0])
    B = make_pose(quat_xyzw_to_rot([0, 0, np.sin(np.pi / 8), np.cos(np.pi / 8)]), [1.0, 2.0, 0.0])  # 45° yaw
    path = write_trajectory(tmp_path / "poses.txt", Trajectory(np.array([10.0, 10.2]), np.stack([A, B])))
    source = TrajectoryPoses.from_file(path, max_time_diff=0.02)
    mid = source.lookup(10.05).pose
    assert np.allclose(mid[:3, 3], [0.25, 0.5, 0.0], atol=1e-6)
    assert np.allclose(mid[:3, :3], quat_xyzw_to_rot([0, 0, np.sin(np.pi / 32), np.cos(np.pi / 32)]), atol=1e-6)
    assert np.allclose(source.lookup(10.21).pose, B, atol=1e-6)  # clamped to the end within max_time_diff
    outside = source.lookup(10.5)
    assert outside.pose is None and "outside" in outside.reason and "poses.txt" in outside.reason


def test_file_poses_refuse_to_bridge_a_gap():
    traj = Trajectory(np.array([0.0, 0.1, 5.0]), np.stack([np.eye(4)] * 3))
    source = TrajectoryPoses(traj, max_gap=1.0)
    assert source.lookup(0.05).pose is not None
    gap = source.lookup(2.0)
    assert gap.pose is None and "gap" in gap.reason
    assert source.lookup(4.99).pose is not None


def _frame(index: int, pose: np.ndarray | None) -> Frame:
    from semmap.types import CameraIntrinsics

    cam = CameraIntrinsics(4, 3, 2.0, 2.0, 2.0, 1.5)
    return Frame(index, index / 30, np.zeros((3, 4, 3), np.uint8), np.zeros((3, 4), np.float32), cam,
                 T_world_cam=pose, name=f"f{index}")


def test_trajectory_of_dataset_skips_frames_without_pose():
    frames = [_frame(0, np.eye(4)), _frame(1, None), _frame(2, make_pose(np.eye(3), [1, 0, 0]))]
    traj = trajectory_of_dataset(frames)
    assert traj.names == ("f0", "f2")
    assert np.allclose(traj.timestamps, [0.0, 2 / 30])


def test_unknown_tracker_is_a_config_error():
    with pytest.raises(ConfigError, match=r"unknown tracker 'magic'; choose from slam"):
        make_tracker("magic")


@pytest.mark.slow
def test_dense_odometry_tracks_a_short_simulated_sequence():
    from semmap.datasets.simulated import SimulatedDataset
    from semmap.poses.odometry import DenseOdometry
    from semmap.types import DEFAULT_INTRINSICS

    sim = SimulatedDataset.default(scene_seed=0, trajectory="desk", frames=20)
    small = SimulatedDataset(sim.scene, sim.poses, seed=0, intrinsics=DEFAULT_INTRINSICS.scaled(0.5))  # fast
    frames = list(small)
    gt = trajectory_of_dataset(frames)
    tracker = DenseOdometry()
    for frame in frames:
        tracker.track(frame)
    est = tracker.trajectory()
    assert len(est) == 20 and est.names == gt.names
    assert np.allclose(est.poses[0], np.eye(4))
    result = evaluate_trajectory(gt, est)
    assert result["ate_rmse_m"] < 0.01
    assert result["rpe_rot_deg"] < 0.2
    assert not tracker.fallbacks

    # A frame without valid depth cannot be aligned: it falls back to the motion model and is flagged.
    broken = [f.with_(depth=np.zeros_like(f.depth)) if f.index == 10 else f for f in frames]
    tracker = DenseOdometry()
    for frame in broken:
        tracker.track(frame)
    assert [r.name for r in tracker.fallbacks] == [frames[10].name]
    assert evaluate_trajectory(gt, tracker.trajectory())["ate_rmse_m"] < 0.02


def test_seven_scenes_ground_truth_evaluates(seven_scenes):
    from semmap.datasets import open_dataset

    gt = trajectory_of_dataset(open_dataset(seven_scenes, max_frames=20))
    result = evaluate_trajectory(gt, gt)
    assert result["matched"] == 20 and result["ate_rmse_m"] < 1e-6


def test_tolerant_reading_keeps_nan_rows_sorts_and_warns_where_strict_stops(tmp_path, caplog):
    path = tmp_path / "gt.txt"
    path.write_text("2.0 2 0 0 0 0 0 1\n0.0 0 0 0 0 0 0 1\n1.0 nan 0 0 0 0 0 1\n2.0 9 9 9 0 0 0 1\n3.0 3 0 0 0 0 0 2\n")
    with caplog.at_level(logging.WARNING, logger="semmap"):
        stamps, rows = read_tum(path)
    assert stamps.tolist() == [0.0, 1.0, 2.0, 2.0, 3.0] and np.isnan(rows[1]).all() and rows[2, 0] == 2.0
    assert "1 poses have non-finite entries or positions beyond ±1e+08 m (lines 3)" in caplog.text
    assert "1 rows repeat" in caplog.text
    assert pose_at(stamps, rows, 0.5, 0.02) is None  # next to the NaN row
    np.testing.assert_allclose(pose_at(stamps, rows, 3.01, 0.02)[:3, 3], [3, 0, 0])  # clamped to the end row
    traj = read_trajectory(path)
    assert traj.timestamps.tolist() == [0.0, 2.0, 3.0] and traj.poses[1, 0, 3] == 2.0
    with pytest.raises(FormatError, match=r"gt\.txt:2: timestamp 0.0 is not after"):
        read_tum(path, strict=True)
    path.write_text("\n".join(path.read_text().splitlines()[1:]) + "\n")
    with pytest.raises(FormatError, match=r"gt\.txt:2: pose has non-finite"):
        read_tum(path, strict=True)


def test_ground_truth_recorder_reads_frames_once_in_time_order_and_matches_trajectory_of_dataset():
    from dataclasses import replace

    frames = [replace(_frame(i, None if i == 1 else make_pose(np.eye(3), [i, 0, 0])), timestamp=t)
              for i, t in enumerate([0.3, 0.1, 0.2, 0.0])]
    recorder = GroundTruthRecorder()
    assert all(a is b for a, b in zip(recorder.watch(iter(frames)), frames, strict=True))
    traj = recorder.trajectory()
    assert traj.names == ("f3", "f2", "f0") and traj.timestamps.tolist() == [0.0, 0.2, 0.3]
    assert traj.poses[:, 0, 3].tolist() == [3.0, 2.0, 0.0]
    same = trajectory_of_dataset(frames)
    assert same.names == traj.names and np.array_equal(same.poses, traj.poses)


def test_whole_file_pose_conversions_equal_the_row_by_row_ones_bit_for_bit() -> None:
    """A million-pose file is converted at once; the result must be the same bits as one row at a time."""
    from scipy.spatial.transform import Rotation

    from semmap.io.trajectory import clean_poses
    from semmap.types import pose_from_tum, pose_to_tum, poses_from_tum, snap_rigid, tum_rows

    rng = np.random.default_rng(7)
    q = Rotation.random(3000, random_state=3).as_quat() * rng.uniform(0.9, 1.1, (3000, 1))
    q[:4] = [[0, 0, 0, 1], [1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0]]  # every branch of Shepperd's method
    rows = np.concatenate([rng.normal(size=(3000, 3)), q], axis=1)
    poses = poses_from_tum(rows)
    assert np.array_equal(poses, np.stack([pose_from_tum(r) for r in rows]))
    assert np.array_equal(tum_rows(poses), np.stack([pose_to_tum(T) for T in poses]))
    drifted = poses.copy()
    drifted[:, :3, :3] += rng.normal(0, 1e-7, (3000, 3, 3))
    assert np.array_equal(clean_poses(drifted, "x"), np.stack([snap_rigid(T) for T in drifted]))
    drifted[5, :3, :3] *= 1.1
    with pytest.raises(Exception, match="x: pose 5 has a rotation that is not orthonormal"):
        clean_poses(drifted, "x")
