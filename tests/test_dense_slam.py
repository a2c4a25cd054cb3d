"""The dense RGB-D SLAM (dense odometry, ORB loop closure and relocalisation, keyframe pose graph)."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from helpers import blank_frame, umeyama_ate
from semmap.errors import ConfigError
from semmap.poses.base import PoseTracker
from semmap.poses.slam import DenseSlam, DenseSlamConfig, dense_slam
from semmap.poses.track import make_tracker
from semmap.types import Frame, pose_change


@pytest.fixture(scope="module")
def desk_frames() -> list[Frame]:
    """The first 60 frames of the simulated desk sequence."""
    from semmap.datasets.simulated import SimulatedDataset

    ds = SimulatedDataset.default(scene_seed=0, trajectory="desk", frames=300)
    return list(itertools.islice(iter(ds), 60))


@pytest.fixture(scope="module")
def chain(desk_frames) -> DenseSlam:
    """The first 40 desk frames tracked with odometry edges only (no loop closure, no covisible edges)."""
    slam = DenseSlam(DenseSlamConfig(loop_closure=False, covisible_edges=0))
    for f in desk_frames[:40]:
        slam.track(f)
    return slam


def _gt(frames: list[Frame], names: tuple[str, ...]) -> np.ndarray:
    by_name = {f.name: f.T_world_cam for f in frames}
    return np.array([by_name[n] for n in names])


@pytest.mark.slow
def test_tracks_the_simulated_desk_to_a_millimetre(desk_frames):
    slam = DenseSlam()
    assert isinstance(slam, PoseTracker) and slam.name == "slam"
    assert np.allclose(slam.track(desk_frames[0]), np.eye(4))
    for f in desk_frames[1:]:
        T = slam.track(f)
        assert T.shape == (4, 4) and np.isfinite(T).all()
    traj = slam.trajectory()
    assert traj.names == tuple(f.name for f in desk_frames)
    assert np.allclose(traj.poses[0], np.eye(4))
    assert umeyama_ate(traj.poses, _gt(desk_frames, traj.names)) < 0.002
    assert slam.stats.keyframes >= 3 and len(slam.keyframes) == slam.stats.keyframes
    for kf in slam.keyframes:  # kept compressed, and given back exactly for rebuilding the pyramids
        depth = desk_frames[kf.frame].depth
        assert np.array_equal(kf.depth.unpack(), depth, equal_nan=True)
        assert kf.depth.unpack().dtype == depth.dtype and kf.grey.unpack().shape == depth.shape
        assert kf.grey.nbytes + kf.depth.nbytes < 0.4 * (depth.nbytes + depth.size)


@pytest.mark.slow
def test_the_same_frames_give_the_same_trajectory_on_every_run(desk_frames):
    """Dense alignment sums in a fixed order, so nothing depends on thread timing: two trackers fed the same frames
    agree to the last bit."""
    first, second = DenseSlam(), DenseSlam()
    for f in desk_frames[:20]:
        assert np.array_equal(first.track(f), second.track(f))
    assert np.array_equal(first.trajectory().poses, second.trajectory().poses)


@pytest.mark.slow
def test_a_revisit_closes_an_accurate_loop(desk_frames, monkeypatch):
    """Out along the desk and back the same way: the way back revisits the first keyframes, which is found as a
    loop; its measured relative pose matches the truth, and the optimised trajectory stays accurate (with room
    for only three keyframes' image pyramids, so the old keyframes' are rebuilt for the loop)."""
    monkeypatch.setattr(dense_slam, "PYRAMID_CACHE", 3)
    out = desk_frames[:40]
    back = [f.with_(timestamp=out[-1].timestamp + 0.05 * (i + 1), name=f"back{i}") for i, f in enumerate(out[::-1])]
    frames = out + back
    truth = {f.name: f.T_world_cam for f in out} | {b.name: f.T_world_cam for f, b in zip(out[::-1], back,
                                                                                         strict=True)}
    for loops in (False, True):
        slam = DenseSlam(DenseSlamConfig(loop_closure=loops, loop_min_gap=4))
        for f in frames:
            slam.track(f)
        assert (slam.stats.loops >= 1) == loops
        # only the last few keyframes' image pyramids stay in memory: a loop to an old one rebuilds its pyramids
        assert len(slam.keyframes) > dense_slam.PYRAMID_CACHE >= len(slam._pyramids)
        traj = slam.trajectory()
        assert umeyama_ate(traj.poses, np.array([truth[n] for n in traj.names])) < 0.002
    gt_kf = np.array([truth[frames[kf.frame].name] for kf in slam.keyframes])
    loop_edges = [(i, j, T) for i, j, T, _ in slam._edges if j - i >= 4]
    assert loop_edges
    for i, j, T in loop_edges:
        dist, angle = pose_change(np.linalg.inv(gt_kf[i]) @ gt_kf[j], T)
        assert dist < 0.003 and angle < 0.2


@pytest.mark.slow
def test_keyframes_are_tied_to_older_keyframes_by_accurate_dense_edges(desk_frames, chain):
    """Besides the odometry chain, each keyframe is aligned to the keyframe before its predecessor; those edges
    measure the true relative pose, and the pose graph they join keeps the trajectory accurate."""
    slam = DenseSlam(DenseSlamConfig(loop_closure=False, covisible_edges=1))
    for f in desk_frames:
        slam.track(f)
    traj = slam.trajectory()
    skips = [(i, j, T) for i, j, T, _ in slam._edges if j - i == 2]
    assert len(skips) >= len(slam.keyframes) - 3 >= 2
    gt_kf = _gt(desk_frames, tuple(desk_frames[kf.frame].name for kf in slam.keyframes))
    for i, j, T in skips:
        dist, angle = pose_change(np.linalg.inv(gt_kf[i]) @ gt_kf[j], T)
        assert dist < 0.003 and angle < 0.2
    assert umeyama_ate(traj.poses, _gt(desk_frames, traj.names)) < 0.002
    assert len(chain.keyframes) >= 3 and not [e for e in chain._edges if e[1] - e[0] != 1]


@pytest.mark.slow
def test_frames_between_keyframes_share_the_next_keyframes_correction(chain, monkeypatch):
    """When the graph moves a keyframe, the frames aligned to the keyframe before it move by a growing part of
    that correction, so the trajectory has no jump where the moved keyframe starts."""
    slam = chain
    before = slam.trajectory().poses
    assert len(slam.keyframes) >= 3
    first, second = slam.keyframes[1].frame, slam.keyframes[2].frame
    assert second - first >= 3
    shift = np.array([0.01, 0.0, 0.0])
    moved_pose = slam.keyframes[2].T_wc.copy()
    moved_pose[:3, 3] += shift
    monkeypatch.setattr(slam.keyframes[2], "T_wc", moved_pose)  # as if the pose graph had moved keyframe 2 by 1 cm
    moved = slam.trajectory().poses[:, :3, 3] - before[:, :3, 3]
    assert np.allclose(moved[: first + 1], 0.0, atol=1e-12)  # keyframe 1 and everything before it stay
    along = (np.arange(first, second + 1) - first) / (second - first)
    assert np.allclose(moved[first : second + 1], along[:, None] * shift, atol=1e-9)


@pytest.mark.slow
def test_relocalises_after_the_sensor_goes_blind(desk_frames):
    slam = DenseSlam(DenseSlamConfig(loop_closure=False))
    for f in desk_frames[:20]:
        slam.track(f)
    stamp = desk_frames[19].timestamp
    for k in range(3):  # no colour and no depth: the dense alignment fails, the motion model carries on
        assert np.isfinite(slam.track(blank_frame(desk_frames[19], stamp + 0.001 * (k + 1)))).all()
    # ... and the camera comes back some frames later, further along the path
    for f in desk_frames[26:]:
        slam.track(f)
    assert slam.stats.relocalisations >= 1
    traj = slam.trajectory()
    real = [i for i, n in enumerate(traj.names) if not n.startswith("blank")]
    assert umeyama_ate(traj.poses[real], _gt(desk_frames, tuple(traj.names[i] for i in real))) < 0.005


def test_tracker_names_and_bad_settings():
    assert isinstance(make_tracker("slam"), DenseSlam)
    assert make_tracker("slam-noloop").slam_config.loop_closure is False
    assert make_tracker("slam-orb").name == "slam-orb"
    with pytest.raises(ConfigError, match="min_inliers"):
        DenseSlamConfig(min_inliers=3)
    with pytest.raises(ConfigError, match="min_fitness"):
        DenseSlamConfig(min_fitness=2.0)
    with pytest.raises(ConfigError, match="positive"):
        DenseSlamConfig(edge_sigma=(0.0, 0.01))
    with pytest.raises(ConfigError, match="covisible_edges"):
        DenseSlamConfig(covisible_edges=-1)
    with pytest.raises(ConfigError, match="DenseSlamConfig"):
        DenseSlam(config="fast")
