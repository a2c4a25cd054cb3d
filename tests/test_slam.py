"""The built-in RGB-D SLAM: PnP, short simulated sequences, pose-graph loop correction, relocalisation, bad input."""

from __future__ import annotations

import itertools

import cv2
import numpy as np
import pytest

from helpers import blank_frame as _blank
from helpers import umeyama_ate as _umeyama_ate
from semmap.errors import ConfigError, DatasetError
from semmap.poses.base import PoseTracker, estimate_trajectory
from semmap.poses.slam import RgbdSlam, SlamConfig, se3
from semmap.poses.slam.optimisation import optimise_pose_graph
from semmap.poses.slam.pose_solver import PinholeModel, pnp_ransac, refine_pose
from semmap.types import CameraIntrinsics, Frame, invert_pose, rotation_angle, snap_rigid, transform_points

CAM = PinholeModel(525.0, 525.0, 319.5, 239.5, 0.08 * 525.0)


@pytest.fixture(scope="module")
def desk_frames() -> list[Frame]:
    """The first 40 frames of the simulated desk sequence (rendered once per module)."""
    from semmap.datasets.simulated import SimulatedDataset

    ds = SimulatedDataset.default(scene_seed=0, trajectory="desk", frames=300)
    return list(itertools.islice(iter(ds), 40))


# ------------------------------------------------------------------------------------------ features
@pytest.mark.parametrize("level", [1, 3, 5, 7])
def test_coarse_level_keypoints_map_to_their_full_resolution_position(level):
    """A blob found on an ORB pyramid level (built like OpenCV's: each level a linear resize of the one before
    to the rounded size) is reported where it lies in the full image, not at the level position times s^l."""
    from semmap.poses.slam.features import OrbExtractor

    cfg = SlamConfig()
    intr = CameraIntrinsics(640, 480, 525.0, 525.0, 319.5, 239.5)
    x0, y0 = 517.3, 401.8  # bottom right, where the nominal scale is furthest off
    yy, xx = np.mgrid[0:480, 0:640]
    image = np.exp(-((xx - x0) ** 2 + (yy - y0) ** 2) / (2 * 12.0**2)).astype(np.float32)
    for k in range(1, level + 1):
        s = cfg.scale_factor ** k
        size = (int(np.floor(640 / s + 0.5)), int(np.floor(480 / s + 0.5)))
        image = cv2.resize(image, size, interpolation=cv2.INTER_LINEAR)
    weight = image**4  # the blob's peak, away from its tails cut by the image border
    ly, lx = np.mgrid[0:image.shape[0], 0:image.shape[1]]
    centre_on_level = np.array([(weight * lx).sum(), (weight * ly).sum()]) / weight.sum()
    reported = centre_on_level[None] * cfg.scale_factor**level  # what OpenCV's ORB returns as the keypoint
    mapped = OrbExtractor(cfg, intr)._level_to_image(reported, np.array([level], np.int32))[0]
    assert np.abs(mapped - [x0, y0]).max() < 0.05
    if level >= 3:
        assert np.abs(reported[0] - [x0, y0]).max() > 0.3  # the uncorrected position is off


# ------------------------------------------------------------------------------------------ PnP
def test_pnp_ransac_and_refinement_recover_a_known_pose_despite_outliers():
    rng = np.random.default_rng(0)
    cv2.setRNGSeed(0)
    T_cw = se3.exp_update(np.array([0.1, -0.05, 0.08, 0.3, -0.2, 0.5]))
    pts_w = rng.uniform([-2, -1.5, 2], [2, 1.5, 5], (300, 3))
    pts_w = transform_points(invert_pose(T_cw), pts_w)  # points in front of the camera
    uv, ur = CAM.project(transform_points(T_cw, pts_w))
    uv = uv + rng.normal(0, 0.5, uv.shape)
    ur = ur + rng.normal(0, 0.3, ur.shape)
    outliers = rng.choice(300, 90, replace=False)
    uv[outliers] = rng.uniform([0, 0], [640, 480], (90, 2))
    ur[:40] = np.nan  # some keypoints without depth
    found = pnp_ransac(pts_w, uv, CAM, None, 3.0, 200, seed=0)
    assert found is not None
    T0, inl = found
    assert not inl[outliers].any() or inl[outliers].mean() < 0.1
    T, ok = refine_pose(T0, pts_w[inl], uv[inl], ur[inl], np.ones(inl.sum()), CAM)
    err = invert_pose(T) @ T_cw
    assert np.linalg.norm(err[:3, 3]) < 5e-3
    assert np.degrees(rotation_angle(err)) < 0.2
    assert ok.mean() > 0.9


def test_pnp_gives_up_on_too_few_points():
    assert pnp_ransac(np.zeros((4, 3)), np.zeros((4, 2)), CAM, None, 3.0, 50) is None


# ------------------------------------------------------------------------------------------ pose graph
def test_pose_graph_with_a_loop_edge_removes_injected_drift():
    n = 24
    true = []
    for k in range(n):  # a circle of radius 2 m, camera looking at the centre
        a = 2 * np.pi * k / n
        R = cv2.Rodrigues(np.array([0.0, -a, 0.0]))[0]
        true.append(snap_rigid(np.block([[R, np.array([[2 * np.sin(a)], [0.0], [2 * np.cos(a)]])],
                                         [np.zeros((1, 3)), np.ones((1, 1))]])))
    true = np.array(true)
    drift = se3.exp_update(np.array([0.0, 0.004, 0.0, 0.01, 0.0, 0.0]))  # per-step bias
    odo = [invert_pose(true[k]) @ true[k + 1] @ drift for k in range(n - 1)]
    est = [true[0]]
    for step in odo:
        est.append(est[-1] @ step)
    est = np.array(est)
    before = np.linalg.norm(est[-1][:3, 3] - true[-1][:3, 3])
    edges = [(k, k + 1, odo[k], 1.0) for k in range(n - 1)]
    edges.append((0, n - 1, invert_pose(true[0]) @ true[n - 1], 1.0))
    fixed = optimise_pose_graph(est, edges, fixed=0)
    after = np.linalg.norm(fixed[-1][:3, 3] - true[-1][:3, 3])
    assert before > 0.15
    assert after < 0.1 * before
    assert _umeyama_ate(fixed, true) < 0.75 * _umeyama_ate(est, true)


# ------------------------------------------------------------------------------------------ sequences
@pytest.mark.slow
def test_short_simulated_sequence_is_tracked_accurately(desk_frames):
    slam = RgbdSlam(SlamConfig(loop_closure=True))
    assert isinstance(slam, PoseTracker) and slam.name == "slam-orb"
    first = slam.track(desk_frames[0])
    assert np.allclose(first, np.eye(4))
    for f in desk_frames[1:]:
        T = slam.track(f)
        assert T is not None and T.shape == (4, 4) and T.dtype == np.float64
    traj = slam.trajectory()
    assert traj.names == tuple(f.name for f in desk_frames)
    assert np.allclose(traj.timestamps, [f.timestamp for f in desk_frames])
    assert np.allclose(traj.poses[0], np.eye(4), atol=1e-9)
    gt = np.array([f.T_world_cam for f in desk_frames])
    assert _umeyama_ate(traj.poses, gt) < 0.01
    assert slam.stats.keyframes >= 2 and slam.stats.lost == 0


@pytest.mark.slow
def test_relocalises_after_blank_frames(desk_frames):
    slam = RgbdSlam(SlamConfig(loop_closure=False))
    for f in desk_frames[:20]:
        slam.track(f)
    stamp = desk_frames[19].timestamp
    for k in range(3):  # the sensor goes blind: tracking is lost, no crash
        assert slam.track(_blank(desk_frames[19], stamp + 0.001 * (k + 1))) is None
    # ... and comes back some frames later, elsewhere along the path
    poses = [slam.track(f) for f in desk_frames[26:]]
    assert all(T is not None for T in poses)
    assert slam.stats.relocalisations >= 1 and slam.stats.lost == 3
    traj = slam.trajectory()
    assert len(traj) == 20 + len(desk_frames) - 26
    by_name = {f.name: f.T_world_cam for f in desk_frames}
    gt = np.array([by_name[n] for n in traj.names])
    assert _umeyama_ate(traj.poses, gt) < 0.02


def test_estimate_trajectory_runs_the_tracker(desk_frames):
    traj = estimate_trajectory(RgbdSlam(), desk_frames[:8])
    assert len(traj) == 8


def test_dense_aligner_recovers_a_relative_pose(desk_frames):
    from semmap.poses.odometry import OdometryConfig

    f0, f6 = desk_frames[0], desk_frames[6]
    true = invert_pose(f0.T_world_cam) @ f6.T_world_cam  # ~5 cm and ~4 degrees
    guess = se3.exp_update(np.array([0.01, -0.01, 0.005, 0.01, 0.01, -0.01])) @ true  # what features would give
    for scale in (1, 2):
        aligner = OdometryConfig(iterations=SlamConfig().dense_iterations).aligner(f0.intrinsics, scale)
        out = aligner.align(aligner.image(f6.rgb, f6.depth), aligner.image(f0.rgb, f0.depth), guess)
        assert out is not None and out.fitness > 0.5
        err = invert_pose(true) @ out.T
        assert np.linalg.norm(err[:3, 3]) < 3e-3
        assert np.degrees(rotation_angle(err)) < 0.2
    blank = aligner.image(np.zeros_like(f0.rgb), np.zeros_like(f0.depth))
    result = aligner.align(blank, aligner.image(f0.rgb, f0.depth), np.eye(4))
    assert result is None or result.fitness < 0.3  # nothing to align: rejected by the fitness gate


@pytest.mark.slow
def test_dense_fallback_carries_tracking_through_textureless_frames(desk_frames):
    # frames 20..24 lose all texture (a flat grey image, depth intact): features cannot track them
    frames = [f.with_(rgb=np.full_like(f.rgb, 128)) if 20 <= i < 25 else f for i, f in enumerate(desk_frames)]
    with_fallback = RgbdSlam(SlamConfig(loop_closure=False))
    for f in frames:
        assert with_fallback.track(f) is not None
    s = with_fallback.stats
    assert s.lost == 0 and s.dense_fallbacks >= 3
    traj = with_fallback.trajectory()
    assert len(traj) == len(frames)
    gt = np.array([f.T_world_cam for f in frames])
    assert _umeyama_ate(traj.poses, gt) < 0.01
    # without the fallback the same frames are lost
    without = RgbdSlam(SlamConfig(loop_closure=False, dense_fallback=False, dense_refine="off"))
    for f in frames[:25]:
        without.track(f)
    assert without.stats.lost >= 3


@pytest.mark.slow
@pytest.mark.parametrize("refine", ["off", "keyframes", "frames"])
def test_dense_refinement_modes_track_the_desk(desk_frames, refine):
    slam = RgbdSlam(SlamConfig(loop_closure=False, dense_refine=refine))
    for f in desk_frames[:24]:
        slam.track(f)
    traj = slam.trajectory()
    gt = np.array([f.T_world_cam for f in desk_frames[:24]])
    assert len(traj) == 24
    assert _umeyama_ate(traj.poses, gt) < 0.006
    assert (slam.stats.dense_refined > 0) == (refine != "off")
    if refine == "frames":
        assert slam.stats.dense_refined >= 20


def test_tracker_names_select_the_dense_refinement():
    from semmap.poses.track import METHODS, make_tracker

    assert {"slam", "slam-noloop", "slam-orb", "slam-features"} <= set(METHODS)
    assert make_tracker("slam-orb").config.dense_refine == "frames"
    assert make_tracker("slam-features").config.dense_refine == "off"


# ------------------------------------------------------------------------------------------ bad input
def test_frames_without_depth_or_texture_do_not_crash(desk_frames):
    f0 = desk_frames[0]
    slam = RgbdSlam()
    assert slam.track(f0.with_(depth=np.zeros_like(f0.depth))) is None  # cannot start a map without depth
    assert slam.track(_blank(f0, 0.01)) is None
    nan_depth = f0.depth.copy()
    nan_depth[:, :200] = np.nan
    assert slam.track(f0.with_(depth=nan_depth, timestamp=0.02)) is not None  # starts the map here
    # once there is a map, a frame without depth is still tracked from its pixels (no new landmarks, though)
    assert slam.track(desk_frames[1].with_(depth=np.zeros_like(f0.depth), timestamp=0.05)) is not None
    assert len(slam.trajectory()) == 2
    assert len(RgbdSlam().trajectory()) == 0


def test_wrong_input_raises_clear_errors(desk_frames):
    slam = RgbdSlam()
    with pytest.raises(DatasetError, match="Frame"):
        slam.track(np.zeros((480, 640, 3)))  # type: ignore[arg-type]
    slam.track(desk_frames[0])
    with pytest.raises(DatasetError, match="timestamp"):
        slam.track(desk_frames[0])
    other = CameraIntrinsics(640, 480, 500.0, 500.0, 320.0, 240.0)
    with pytest.raises(DatasetError, match="intrinsics"):
        slam.track(desk_frames[1].with_(intrinsics=other))
    with pytest.raises(ConfigError):
        RgbdSlam("fast")  # type: ignore[arg-type]
    with pytest.raises(ConfigError):
        SlamConfig(n_features=0)
    with pytest.raises(ConfigError):
        SlamConfig(min_depth=5.0, max_depth=1.0)
    with pytest.raises(ConfigError):
        SlamConfig(match_ratio=1.5)
    with pytest.raises(ConfigError, match="dense_refine"):
        SlamConfig(dense_refine="always")
    with pytest.raises(ConfigError, match="dense_iterations"):
        SlamConfig(dense_iterations=())
    with pytest.raises(ConfigError, match="dense_scale"):
        SlamConfig(dense_scale=0)


# ------------------------------------------------------------------------------------------ real data
@pytest.mark.slow
def test_seven_scenes_start_is_tracked(seven_scenes):
    from semmap.datasets import open_dataset

    frames = list(open_dataset(seven_scenes, max_frames=60))
    slam = RgbdSlam()
    for f in frames:
        slam.track(f)
    traj = slam.trajectory()
    assert len(traj) >= 55
    by_name = {f.name: f.T_world_cam for f in frames}
    gt = np.array([by_name[n] for n in traj.names])
    assert _umeyama_ate(traj.poses, gt) < 0.05
