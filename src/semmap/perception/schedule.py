"""Which frames get segmented: every k-th frame, or keyframes (the camera moved enough since the last one).

Segmentation is the most expensive per-frame step; mapping still integrates every frame's geometry and colour,
but class probabilities reach the map only from the frames segmented.  Offline, segmented frames are batched
for the network while the frames between them wait (``with_semantics``); online, a ``SegmentationWorker``
segments due frames on a thread beside tracking (``with_semantics_beside``).  Either way the map sees frames in
their original order.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from collections.abc import Iterable, Iterator, Sequence
from concurrent.futures import Future
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

    def state(self) -> dict[str, np.ndarray]:
        """Frames seen and the pose of the last one due (a checkpoint's schedule)."""
        last = np.full((4, 4), np.nan) if self._last_pose is None else self._last_pose
        return {"count": np.int64(self._count), "last_pose": np.asarray(last, np.float64)}

    def restore(self, state: dict[str, np.ndarray]) -> None:
        """Continue from :meth:`state`."""
        self._count = int(state["count"])
        last = np.asarray(state["last_pose"], np.float64).reshape(4, 4)
        self._last_pose = None if np.isnan(last).all() else last

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


def as_posed(frame: Frame, T_world_cam: np.ndarray | None, segmenter: Segmenter) -> Frame:
    """The frame as ``segmenter`` wants it: with the run's pose for one that uses poses (the structure segmenter
    carries gravity and the floor between frames by them), else as it is."""
    if T_world_cam is None or not getattr(segmenter, "uses_pose", False) or frame.T_world_cam is T_world_cam:
        return frame
    return frame.with_(T_world_cam=np.asarray(T_world_cam, np.float64))


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
        results = iter(segment_many(segmenter, [as_posed(f, T, segmenter) for f, T, due in pending if due]))
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


class SegmentationWorker:
    """Segments frames on one background thread while the caller goes on (tracking, mapping).

    At most ``max_queued`` frames are queued or being segmented: ``submit`` blocks beyond that, so a slow network
    holds the camera loop back instead of buffering frames without bound.  The thread runs numba's kernels (the
    network's top-k resampling) on ``numba_threads`` threads, leaving the other cores to the caller's.
    """

    def __init__(self, segmenter: Segmenter, *, max_queued: int = 2, numba_threads: int = 1):
        if max_queued < 1:
            raise ConfigError(f"a segmentation queue needs room for at least one frame, got {max_queued}")
        from concurrent.futures import ThreadPoolExecutor

        self.segmenter = segmenter
        self._slots = threading.BoundedSemaphore(max_queued)
        self._pool = ThreadPoolExecutor(1, thread_name_prefix="semmap-segment", initializer=_limit_numba_threads,
                                        initargs=(numba_threads,))

    def submit(self, frame: Frame) -> Future:
        """Start segmenting ``frame``; the future gives ``(semantics, milliseconds)``."""
        self._slots.acquire()
        try:
            future = self._pool.submit(self._segment, frame)
        except BaseException:
            self._slots.release()
            raise
        future.add_done_callback(lambda _: self._slots.release())
        return future

    def _segment(self, frame: Frame) -> tuple[TopKProbs, float]:
        t0 = time.perf_counter()
        sem = self.segmenter.segment(frame)
        return sem, (time.perf_counter() - t0) * 1e3

    def close(self) -> None:
        """Stop the thread (frames not started yet are dropped)."""
        self._pool.shutdown(wait=True, cancel_futures=True)

    def __enter__(self) -> SegmentationWorker:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _limit_numba_threads(n: int) -> None:
    import numba

    numba.set_num_threads(max(1, min(int(n), numba.config.NUMBA_NUM_THREADS)))  # per thread in numba


def with_semantics_beside(posed: Iterable[tuple[Frame, np.ndarray]], worker: SegmentationWorker,
                          scheduler: Scheduler, *, max_pending: int = 8, timings: dict[str, float] | None = None
                          ) -> Iterator[tuple[Frame, np.ndarray, TopKProbs | None]]:
    """``(frame, pose, semantics or None)`` in input order, each as soon as it can be: frames not due come out
    at once unless an earlier due frame is still being segmented (order is kept, so the map sees frames as an
    offline run does); due frames are segmented by ``worker`` beside the caller.  At most ``max_pending`` frames
    wait here; beyond that the oldest due frame is waited for.  Milliseconds: ``timings["segment"]`` the worker's
    time, ``timings["segment_wait"]`` the caller's time blocked on it."""
    if max_pending < 1:
        raise ConfigError(f"max_pending must be at least 1, got {max_pending}")
    pending: deque[tuple[Frame, np.ndarray, Future | None]] = deque()

    def ready(block: bool) -> Iterator[tuple[Frame, np.ndarray, TopKProbs | None]]:
        while pending:
            frame, T, future = pending[0]
            if future is not None and not future.done():
                if not block:
                    return
                t0 = time.perf_counter()
                future.result()
                _add(timings, "segment_wait", (time.perf_counter() - t0) * 1e3)
            pending.popleft()
            sem = frame.semantics
            if future is not None:
                sem, ms = future.result()
                _add(timings, "segment", ms)
            yield frame, T, sem

    for frame, T in posed:
        due = frame.semantics is None and scheduler.due(T)
        pending.append((frame, T, worker.submit(as_posed(frame, T, worker.segmenter)) if due else None))
        yield from ready(block=False)
        while len(pending) >= max_pending:
            yield from _first(ready(block=True))
    yield from ready(block=True)


def _first(it: Iterator) -> Iterator:
    """The first item of ``it`` only (the rest is not computed)."""
    for item in it:
        yield item
        return


def _add(timings: dict[str, float] | None, key: str, ms: float) -> None:
    if timings is not None:
        timings[key] = timings.get(key, 0.0) + ms
