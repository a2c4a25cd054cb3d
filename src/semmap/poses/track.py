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

from collections.abc import Callable, Iterable
from dataclasses import dataclass

from semmap.errors import ConfigError
from semmap.poses.base import PoseTracker, Progress, estimate_trajectory
from semmap.registry import Registry, name_enum
from semmap.types import Frame, Trajectory


@dataclass(frozen=True)
class TrackerEntry:
    """A tracker by name: its factory (no arguments, a fresh tracker), one line of help, and what it can do."""

    name: str
    factory: Callable[[], PoseTracker]
    help: str
    objects: bool = True  #: has an ``X-objects`` variant (object-constrained keyframe poses, needs instances)
    needs: str | None = None  #: optional package it needs (installed separately)


def _slam(**config) -> Callable[[], PoseTracker]:
    def make() -> PoseTracker:
        try:
            from semmap.poses.slam import DenseSlam, DenseSlamConfig
        except ImportError as exc:
            raise ConfigError(f"dense SLAM is not available: semmap.poses.slam cannot be imported ({exc})") from None
        return DenseSlam(DenseSlamConfig(**config)) if config else DenseSlam()

    return make


def _feature_slam(**config) -> Callable[[], PoseTracker]:
    def make() -> PoseTracker:
        try:
            from semmap.poses.slam import RgbdSlam, SlamConfig
        except ImportError as exc:
            raise ConfigError(f"feature SLAM is not available: semmap.poses.slam cannot be imported ({exc})") from None
        return RgbdSlam(SlamConfig(**config)) if config else RgbdSlam()

    return make


def _odometry() -> PoseTracker:
    from semmap.poses.odometry import DenseOdometry

    return DenseOdometry()


def _open3d_legacy() -> PoseTracker:
    from semmap.poses.open3d_peers import Open3dLegacyOdometry

    return Open3dLegacyOdometry()


def _open3d_tensor() -> PoseTracker:
    from semmap.poses.open3d_peers import Open3dTensorOdometry

    return Open3dTensorOdometry()


#: Every tracker ``--poses`` / ``semmap track --method`` can name; the first is ``semmap track``'s default.
TRACKERS: Registry[TrackerEntry] = Registry("tracker", [
    TrackerEntry("slam", _slam(), "dense SLAM: dense odometry, ORB loop closure and relocalisation, keyframe "
                 "pose graph"),
    TrackerEntry("slam-noloop", _slam(loop_closure=False), "the dense SLAM without loop closure"),
    TrackerEntry("slam-orb", _feature_slam(), "ORB-SLAM2-style feature SLAM with dense refinement of its poses"),
    TrackerEntry("slam-features", _feature_slam(dense_refine="off"), "the ORB feature SLAM alone"),
    TrackerEntry("odometry", _odometry, "dense RGB-D odometry (frame to keyframe, no map)"),
    TrackerEntry("open3d-f2f", _open3d_legacy, "Open3D's legacy frame-to-frame RGB-D odometry (a peer)",
                 objects=False, needs="open3d"),
    TrackerEntry("open3d-f2f-tensor", _open3d_tensor, "Open3D's tensor frame-to-frame RGB-D odometry (a peer)",
                 objects=False, needs="open3d"),
], option="--poses or track --method")
#: Tracker names accepted by :func:`make_tracker`.
METHODS: tuple[str, ...] = TRACKERS.names
#: Pose sources ``X-objects``: tracker X with object-constrained keyframe poses (:mod:`semmap.object_slam`).
OBJECTS_SUFFIX = "-objects"
OBJECT_METHODS: tuple[str, ...] = tuple(f"{m}{OBJECTS_SUFFIX}" for m in TRACKERS.where(objects=True))
#: Poses from the dataset itself (its ground truth), not a tracker.
GROUND_TRUTH = "gt"
#: What ``--poses`` names besides a trajectory file: ``gt``, every tracker, every ``X-objects``.
POSE_SOURCES: tuple[str, ...] = (GROUND_TRUTH, *METHODS, *OBJECT_METHODS)
PoseSource = name_enum("PoseSource", __name__, POSE_SOURCES)


def pose_sources_help() -> str:
    """``--poses`` help: the ground truth, the trackers, their object variants, a trajectory file."""
    return (f"{GROUND_TRUTH} (the dataset's) | {TRACKERS.choices()} | X{OBJECTS_SUFFIX} (tracker X with "
            f"object-constrained keyframes, needs --instances; X one of {', '.join(TRACKERS.where(objects=True))}) "
            f"| PATH of a TUM trajectory")


def make_tracker(method: str) -> PoseTracker:
    """A fresh tracker named ``method`` (one of :data:`TRACKERS`); a ConfigError listing them otherwise."""
    return TRACKERS[method].factory()


def track_dataset(dataset: Iterable[Frame], method: str = METHODS[0], progress: Progress | None = None) -> Trajectory:
    """Camera trajectory of a dataset (or any frame iterable) estimated by the tracker named ``method``."""
    tracker = make_tracker(method)
    total = len(dataset) if hasattr(dataset, "__len__") else 0
    return estimate_trajectory(tracker, dataset, total=total, progress=progress)
