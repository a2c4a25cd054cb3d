"""Which frames get segmented: every k-th frame, or keyframes (the camera moved enough since the last one).

Segmentation is the most expensive per-frame step; mapping still integrates every frame's geometry and colour,
but class probabilities reach the map only from the frames segmented.  Segmented frames are batched for the
network while the frames between them wait, so the map sees frames in their original order.
"""

from __future__ import annotations

import time
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass

import numpy as np

from semmap.errors import ConfigError
from semmap.perception.base import Segmenter
from semmap.types import Frame, TopKProbs, pose_change


@dataclass(frozen=True)
class SegmentationSchedule:
    """Segment every ``every``-th frame; with ``keyframes``, only those where the camera moved at least
    ``min_translation`` metres or turned ``min_rotation_deg`` degrees since the last segmented frame."""

    every: int = 1
    keyframes: bool = False
    min_translation: float = 0.10
    min_rotation_deg: float = 10.0

    def __post_init__(self) -> None:
        if self.every < 1:
            raise ConfigError(f"segment every k-th frame needs k >= 1, got {self.every}")
        if self.min_translation < 0 or self.min_rotation_deg < 0:
            raise ConfigError("keyframe thresholds must be non-negative")


class Scheduler:
    """Stateful application of a :class:`SegmentationSchedule` to a stream of posed frames."""

    def __init__(self, schedule: SegmentationSchedule):
        self.schedule = schedule
        self._count = 0
        self._last_pose: np.ndarray | None = None

    def due(self, T_world_cam: np.ndarray) -> bool:
        """Whether the next frame (seen from ``T_world_cam``) is to be segmented."""
        s = self.schedule
        on_stride = self._count % s.every == 0
        self._count += 1
        if not on_stride:
            return False
        if s.keyframes and self._last_pose is not None and not self._moved(T_world_cam):
            return False
        self._last_pose = np.asarray(T_world_cam, np.float64)
        return True

    def _moved(self, T: np.ndarray) -> bool:
        dt, angle = pose_change(self._last_pose, T)
        return dt >= self.schedule.min_translation or angle >= self.schedule.min_rotation_deg


def segment_many(segmenter: Segmenter, frames: Sequence[Frame]) -> list[TopKProbs | None]:
    """Segment frames in one batch when the segmenter can (networks), else one by one."""
    batch = getattr(segmenter, "segment_batch", None)
    if batch is not None and len(frames) > 1:
        return list(batch(frames))
    return [segmenter.segment(f) for f in frames]


def with_semantics(posed: Iterable[tuple[Frame, np.ndarray]], segmenter: Segmenter, scheduler: Scheduler, *,
                   batch_size: int = 1, timings: dict[str, float] | None = None
                   ) -> Iterator[tuple[Frame, np.ndarray, TopKProbs | None]]:
    """``(frame, pose, semantics or None)`` in input order; due frames are segmented ``batch_size`` at a time
    (milliseconds spent go to ``timings["segment"]``)."""
    pending: list[tuple[Frame, np.ndarray, bool]] = []

    def flush() -> Iterator[tuple[Frame, np.ndarray, TopKProbs | None]]:
        t0 = time.perf_counter()
        results = iter(segment_many(segmenter, [f for f, _, due in pending if due]))
        if timings is not None:
            timings["segment"] = timings.get("segment", 0.0) + (time.perf_counter() - t0) * 1e3
        for frame, T, due in pending:
            yield frame, T, next(results) if due else frame.semantics
        pending.clear()

    due_count = 0
    for frame, T in posed:
        due = frame.semantics is None and scheduler.due(T)  # frames may bring their own class probabilities
        pending.append((frame, T, due))
        due_count += due
        if due_count >= batch_size or due_count == 0:
            yield from flush()
            due_count = 0
    if pending:
        yield from flush()
