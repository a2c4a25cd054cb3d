"""Frames read ahead on a thread: decoding and colour registration of the next frames overlap the work on this one.

Image decoding (OpenCV) and the colour-to-depth resampling release the GIL, so an online run reads frame i+1
while it tracks and maps frame i.  At most ``depth`` frames wait read: the reader stops there rather than
running ahead of the loop without bound.  With a ``rate``, frames are replayed as a live camera delivers them:
frame i is read no earlier than i / rate seconds after the first, and that moment is its arrival.
"""

from __future__ import annotations

import itertools
import queue
import threading
import time
from collections.abc import Iterable, Iterator

from semmap.types import Frame

_DONE = object()
#: Seconds between checks of the stop flag while the queue is full or empty.
_POLL_S = 0.05


class Prefetcher:
    """Iterate ``frames`` on a background thread; iterating the prefetcher gives ``(frame, seconds)`` in order,
    with the ``time.perf_counter()`` at which the frame was read, or was due at ``rate`` (when it "arrived").  Use
    it as a context manager: leaving it stops the reader, also when the loop stops early."""

    def __init__(self, frames: Iterable[Frame], *, depth: int = 2, rate: float | None = None):
        if rate is not None and not rate > 0:
            raise ValueError(f"a replay rate must be positive frames per second, got {rate}")
        self._queue: queue.Queue = queue.Queue(maxsize=max(1, int(depth)))
        self._stop = threading.Event()
        self._rate = rate
        self._thread = threading.Thread(target=self._read, args=(iter(frames),), name="semmap-read", daemon=True)
        self._thread.start()

    def _read(self, it: Iterator[Frame]) -> None:
        try:
            start = time.perf_counter()
            for i in itertools.count():
                due = None if self._rate is None else start + i / self._rate
                if due is not None and self._stop.wait(max(0.0, due - time.perf_counter())):
                    return  # (stopped while waiting for the frame's time)
                frame = next(it, _DONE)
                if frame is _DONE:
                    break
                if not self._put((frame, time.perf_counter() if due is None else due)):
                    return
            self._put(_DONE)
        except BaseException as exc:  # handed to the consumer, which raises it
            self._put(exc)

    def _put(self, item) -> bool:
        while not self._stop.is_set():
            try:
                self._queue.put(item, timeout=_POLL_S)
                return True
            except queue.Full:
                continue
        return False

    def __iter__(self) -> Iterator[tuple[Frame, float]]:
        while True:
            item = self._queue.get()
            if item is _DONE:
                return
            if isinstance(item, BaseException):
                raise item
            yield item

    def close(self) -> None:
        self._stop.set()
        self._thread.join()

    def __enter__(self) -> Prefetcher:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
