"""Pose trackers by name, and one call that tracks a whole dataset (what ``semmap track`` runs)."""

from __future__ import annotations

from collections.abc import Iterable

from semmap.errors import ConfigError
from semmap.poses.base import PoseTracker, Progress, estimate_trajectory
from semmap.types import Frame, Trajectory

#: Tracker names accepted by :func:`make_tracker`.
METHODS: tuple[str, ...] = ("slam", "slam-noloop", "odometry", "open3d-f2f", "open3d-f2f-tensor")


def make_tracker(method: str) -> PoseTracker:
    """A fresh tracker: "slam" (feature SLAM with loop closure), "slam-noloop", "odometry" (dense RGB-D
    odometry), or the plain Open3D frame-to-frame peers "open3d-f2f" (legacy) and "open3d-f2f-tensor"."""
    if method in ("slam", "slam-noloop"):
        try:
            from semmap.poses.slam import RgbdSlam, SlamConfig
        except ImportError as exc:
            raise ConfigError(f"pose method {method!r} is not available: semmap.poses.slam cannot be "
                              f"imported ({exc})") from None
        return RgbdSlam(SlamConfig(loop_closure=False)) if method == "slam-noloop" else RgbdSlam()
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
