"""Pose trackers by name, and one call that tracks a whole dataset (what ``semmap track`` runs).

``slam`` (the default of ``semmap track``) is the dense SLAM (:class:`~semmap.poses.slam.DenseSlam`): dense
photometric + geometric odometry for every frame, ORB loop closure and relocalisation, a keyframe pose graph. It
was chosen by measurement (``benchmarks/bench_tracking.py``, 2 CPU cores, 640x480; numbers in
``docs/BENCHMARKS.md``): on 600 7-Scenes frames it is the most accurate of semmap's trackers, and on the simulated
sequences its ATE is 0.01-0.05 cm against 0.09-0.17 cm for the feature SLAM ``slam-orb`` (3-9x) and 0.21-2.17 cm
for ``slam-features``. ``slam-orb`` is the ORB-SLAM2-style feature SLAM with dense refinement of its poses,
``slam-features`` the same without it.
"""

from __future__ import annotations

from collections.abc import Iterable

from semmap.errors import ConfigError
from semmap.poses.base import PoseTracker, Progress, estimate_trajectory
from semmap.types import Frame, Trajectory

#: Tracker names accepted by :func:`make_tracker`.
METHODS: tuple[str, ...] = ("slam", "slam-noloop", "slam-orb", "slam-features", "odometry", "open3d-f2f",
                            "open3d-f2f-tensor")


def make_tracker(method: str) -> PoseTracker:
    """A fresh tracker: "slam" (dense SLAM with loop closure), "slam-noloop" (without it), "slam-orb" (ORB feature
    SLAM with dense refinement), "slam-features" (ORB feature SLAM alone), "odometry" (dense RGB-D odometry), or
    the plain Open3D frame-to-frame peers "open3d-f2f" (legacy) and "open3d-f2f-tensor"."""
    if method in ("slam", "slam-noloop", "slam-orb", "slam-features"):
        try:
            from semmap.poses.slam import DenseSlam, DenseSlamConfig, RgbdSlam, SlamConfig
        except ImportError as exc:
            raise ConfigError(f"pose method {method!r} is not available: semmap.poses.slam cannot be "
                              f"imported ({exc})") from None
        if method == "slam":
            return DenseSlam()
        if method == "slam-noloop":
            return DenseSlam(DenseSlamConfig(loop_closure=False))
        if method == "slam-features":
            return RgbdSlam(SlamConfig(dense_refine="off"))
        return RgbdSlam()
    if method == "odometry":
        from semmap.poses.odometry import DenseOdometry

        return DenseOdometry()
    if method == "open3d-f2f":
        from semmap.poses.open3d_peers import Open3dLegacyOdometry

        return Open3dLegacyOdometry()
    if method == "open3d-f2f-tensor":
        from semmap.poses.open3d_peers import Open3dTensorOdometry

        return Open3dTensorOdometry()
    raise ConfigError(f"unknown pose method {method!r}; known: {', '.join(METHODS)}")


def track_dataset(dataset: Iterable[Frame], method: str = "slam", progress: Progress | None = None) -> Trajectory:
    """Camera trajectory of a dataset (or any frame iterable) estimated by the tracker named ``method``."""
    tracker = make_tracker(method)
    total = len(dataset) if hasattr(dataset, "__len__") else 0
    return estimate_trajectory(tracker, dataset, total=total, progress=progress)
