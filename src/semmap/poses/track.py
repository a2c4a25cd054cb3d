"""Pose trackers by name, and one call that tracks a whole dataset (what ``semmap track`` runs).

``slam`` (the default of ``--poses slam``) is the feature SLAM (ORB, local map tracking, local BA, loop closure)
whose every feature-tracked pose is refined by dense photometric + geometric alignment to its reference keyframe
(half resolution), with dense relative-pose factors between keyframes in bundle adjustment and a dense fallback
that carries tracking through views without features. It was chosen by measurement (benchmarks/bench_tracking.py,
2 CPU cores, 640x480) as the most accurate tracker that runs at >= 15 frames/s: ~58 ms/frame and ATE ~3.7 cm on
600 frames of 7-Scenes redkitchen (features alone: ~46 ms/frame, ~3.6 cm; ``odometry``: ~115 ms/frame, ~4.1 cm),
and 2-4x more accurate than features alone on the simulated sequences (e.g. sim-loop ~0.5 cm against ~1.7 cm).
``slam-features`` is the same SLAM without the per-frame dense refinement (the dense fallback stays on).
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
    """A fresh tracker: "slam" (feature SLAM with loop closure), "slam-noloop", "slam-features" (feature SLAM
    without the per-frame dense refinement), "odometry" (dense RGB-D odometry), or the plain Open3D
    frame-to-frame peers "open3d-f2f" (legacy) and "open3d-f2f-tensor"."""
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
