"""The pose-source interface: frames in, camera poses ``T_world_cam`` out.

A :class:`PoseTracker` sees frames one at a time (``track``), may revise earlier poses later (bundle
adjustment, loop closure), and hands back its final, optimised trajectory (``trajectory``).  Sources that
know every pose up front (ground truth, a trajectory file) are plain :class:`~semmap.types.Trajectory` lookups.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
from typing import Protocol, runtime_checkable

import numpy as np

from semmap.types import Frame, Trajectory

#: A progress wrapper ``(iterator, total) -> iterator`` (the CLI passes a progress bar).
Progress = Callable[[Iterator, int], Iterator]


@runtime_checkable
class PoseTracker(Protocol):
    """Estimates camera poses from the images themselves (visual odometry or SLAM)."""

    #: Short name used in reports and benchmarks (``slam``, ``odometry``, ...).
    name: str

    def track(self, frame: Frame) -> np.ndarray | None:
        """Current estimate of ``T_world_cam`` for ``frame`` (the first frame defines the world), or None
        when tracking is lost for this frame."""
        ...

    def trajectory(self) -> Trajectory:
        """Final poses of every frame that was tracked, after any global optimisation, with frame names."""
        ...


@runtime_checkable
class LiveTracker(Protocol):
    """A tracker whose global optimisation (a closed loop, a pose graph) moves poses after ``track`` returned
    them: ``live_pose`` is the latest frame's pose as the tracker now believes it, what an online run maps with."""

    def live_pose(self) -> np.ndarray | None:
        """``T_world_cam`` of the frame tracked last, through the current optimised poses."""
        ...

    @property
    def loop_closures(self) -> int:
        """Loops closed so far (each moved poses already handed out)."""
        ...


def estimate_trajectory(tracker: PoseTracker, frames: Iterable[Frame], total: int = 0,
                        progress: Progress | None = None) -> Trajectory:
    """Run ``tracker`` over ``frames`` (with an optional progress wrapper) and return its final trajectory."""
    it: Iterator[Frame] = iter(frames)
    if progress is not None:
        it = progress(it, total)
    for frame in it:
        tracker.track(frame)
    return tracker.trajectory()
