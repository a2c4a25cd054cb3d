"""The pose of each frame of a run from one source, and the trajectories a run reports: the poses it mapped with
and the frames' own ground truth."""

from __future__ import annotations

import time

import numpy as np

from semmap.poses.base import LiveTracker, PoseTracker
from semmap.poses.file import GroundTruthRecorder
from semmap.types import Frame, Trajectory


class FramePoses:
    """Pose of each frame from one source (ground truth, a trajectory lookup or a tracker's poses by frame
    name); remembers the poses used and the frames' own ground truth, for ``trajectory.txt`` and its score."""

    def __init__(self, source: str, *, by_name: dict[str, np.ndarray] | None = None, lookup=None,
                 tracking_s: float | None = None, tracked: int = 0, tracker: PoseTracker | None = None,
                 edge_stats: dict | None = None):
        self.source, self.by_name, self.lookup = source, by_name, lookup
        self.tracking_s, self.tracked = tracking_s, tracked
        self.edge_stats = edge_stats  # what object constraints did to the trajectory (X-objects trackers)
        self.tracker = tracker  # online: tracked frame by frame, as the frames arrive
        self._used: list[tuple[float, str, np.ndarray]] = []
        self._gt = GroundTruthRecorder()

    def __call__(self, frame: Frame) -> tuple[np.ndarray | None, str]:
        """(pose or None, why not)."""
        if self.tracker is not None:
            T, reason = self._track(frame), f"{self.source} tracking lost"
        elif self.by_name is not None:
            T = self.by_name.get(frame.name)
            reason = "" if T is not None else f"{self.source} tracking lost"
        elif self.lookup is not None:
            found = self.lookup.pose_of(frame)
            T, reason = found.pose, found.reason
        else:
            T, reason = frame.T_world_cam, "no ground-truth pose"
        self._gt.add(frame)
        if T is not None:
            self._used.append((frame.timestamp, frame.name, T))
        return T, reason

    def _track(self, frame: Frame) -> np.ndarray | None:
        """The tracker's pose of a new frame, through its latest global optimisation where it has one."""
        t0 = time.perf_counter()
        T = self.tracker.track(frame)
        if T is not None and isinstance(self.tracker, LiveTracker):
            T = self.tracker.live_pose()
        self.tracking_s = (self.tracking_s or 0.0) + time.perf_counter() - t0
        self.tracked += T is not None
        return None if T is None else np.array(T, np.float64)

    def used_trajectory(self) -> Trajectory:
        """The poses frames were mapped with, in time order."""
        return Trajectory.from_rows(self._used)

    def ground_truth(self) -> Trajectory:
        """The frames' own ground-truth poses, in time order."""
        return self._gt.trajectory()

    def state(self) -> dict:
        """What a checkpoint keeps of an offline pose source (poses by frame name and what was recorded so far)."""
        return {"source": self.source, "by_name": self.by_name, "tracking_s": self.tracking_s,
                "tracked": self.tracked, "edge_stats": self.edge_stats, "used": self._used}
