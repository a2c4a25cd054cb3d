"""Poses known up front: a trajectory file looked up by frame timestamp, and a dataset's own ground truth."""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from semmap.errors import ConfigError
from semmap.io.trajectory import pose_at, read_trajectory
from semmap.types import Frame, Trajectory, tum_rows


@dataclass(frozen=True)
class PoseLookup:
    """Pose of one frame from a trajectory, or None and why (outside the trajectory, in a gap)."""

    pose: np.ndarray | None
    reason: str = ""


class TrajectoryPoses:
    """Pose of a frame by timestamp: interpolated between the bracketing trajectory poses (linear translation,
    slerp rotation), clamped to an end pose within ``max_time_diff`` of the trajectory's time range.

    Frames further outside the trajectory, or between two poses more than ``max_gap`` seconds apart (and not
    within ``max_time_diff`` of either), get no pose.
    """

    def __init__(self, trajectory: Trajectory, *, max_time_diff: float = 0.02, max_gap: float = 0.5,
                 source: str = "trajectory") -> None:
        if len(trajectory) == 0:
            raise ConfigError(f"{source}: trajectory has no poses")
        if not max_time_diff >= 0 or not max_gap > 0:
            raise ConfigError(f"max_time_diff must be >= 0 and max_gap > 0 seconds, got {max_time_diff}, {max_gap}")
        self.trajectory = trajectory
        self.max_time_diff = float(max_time_diff)
        self.max_gap = float(max_gap)
        self.source = source
        self._stamps = trajectory.timestamps
        self._rows = tum_rows(trajectory.poses)

    @classmethod
    def from_file(cls, path: str | Path, **kwargs) -> TrajectoryPoses:
        """Pose source for a TUM trajectory file (``--poses PATH``)."""
        return cls(read_trajectory(path, strict=True), source=str(path), **kwargs)

    def lookup(self, timestamp: float) -> PoseLookup:
        """Pose at ``timestamp`` or None with the reason."""
        t = float(timestamp)
        stamps = self._stamps
        if t < stamps[0] - self.max_time_diff or t > stamps[-1] + self.max_time_diff:
            return PoseLookup(None, f"t={t:.6f} is outside {self.source}'s time range "
                                    f"[{stamps[0]:.6f}, {stamps[-1]:.6f}] (± {self.max_time_diff} s)")
        j = int(np.searchsorted(stamps, t, side="right"))
        if 0 < j < len(stamps):
            before, after = stamps[j - 1], stamps[j]
            near = min(t - before, after - t) <= self.max_time_diff
            if after - before > self.max_gap and not near:
                return PoseLookup(None, f"t={t:.6f} falls in a {after - before:.3f} s gap of {self.source} "
                                        f"(max {self.max_gap} s)")
        pose = pose_at(stamps, self._rows, t, self.max_time_diff)
        return PoseLookup(pose, "" if pose is not None else "no pose")

    def pose_of(self, frame: Frame) -> PoseLookup:
        """Pose for ``frame`` (by its timestamp)."""
        return self.lookup(frame.timestamp)

    def poses_for(self, frames: Iterable[Frame]) -> list[PoseLookup]:
        """Pose for each frame, in order."""
        return [self.pose_of(f) for f in frames]


class GroundTruthRecorder:
    """The frames' own ground-truth poses, recorded as the frames stream past (so a dataset is read once) and
    given back as one :class:`Trajectory` in time order; frames without a pose are left out."""

    def __init__(self) -> None:
        self._rows: list[tuple[float, str, np.ndarray]] = []

    def add(self, frame: Frame) -> None:
        """Record ``frame``'s pose, if it has one (named by the frame's name, else its index)."""
        if frame.T_world_cam is not None:
            self._rows.append((frame.timestamp, frame.name or str(frame.index),
                               np.asarray(frame.T_world_cam, np.float64)))

    @property
    def rows(self) -> list[tuple[float, str, np.ndarray]]:
        """``(timestamp, frame name, T_world_cam)`` recorded so far, in the order seen."""
        return list(self._rows)

    def extend(self, rows: Iterable[tuple[float, str, np.ndarray]]) -> None:
        """Add rows recorded elsewhere (a checkpoint's)."""
        self._rows.extend((float(t), str(name), np.asarray(T, np.float64)) for t, name, T in rows)

    def watch(self, frames: Iterable[Frame]) -> Iterator[Frame]:
        """``frames`` unchanged, each one's pose recorded on the way."""
        for frame in frames:
            self.add(frame)
            yield frame

    def trajectory(self) -> Trajectory:
        """The poses recorded so far, sorted by timestamp."""
        return Trajectory.from_rows(self._rows)


def trajectory_of_dataset(dataset: Iterable[Frame]) -> Trajectory:
    """Ground truth of a dataset (or any frame iterable) as a Trajectory, skipping frames without a pose.

    Reads every frame of a dataset; pass an in-memory list of frames to avoid decoding images twice, or record
    the poses while the frames are used (:class:`GroundTruthRecorder`).
    """
    recorder = GroundTruthRecorder()
    for frame in dataset:
        recorder.add(frame)
    return recorder.trajectory()
