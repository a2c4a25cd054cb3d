"""Ctrl-C during a run: the first one asks the run to stop at its next safe point (between frames), so it never
lands inside a numba kernel as a ``SystemError``; a second one stops at once.

``deferred_interrupts()`` installs the handler for a ``with`` block (main thread only); ``stop_requested()`` is
polled by the run; :class:`RunInterrupted` carries the one line the command prints before exiting with 130.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Iterator

_requested = threading.Event()


class RunInterrupted(KeyboardInterrupt):
    """A run stopped on Ctrl-C at a safe point; ``str()`` says after which frame and what was kept."""


def stop_requested() -> bool:
    return _requested.is_set()


@contextlib.contextmanager
def deferred_interrupts() -> Iterator[None]:
    """First SIGINT sets the stop flag; a second raises KeyboardInterrupt as usual. Outside the main thread (Ray
    workers, threads) nothing is installed."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    _requested.clear()

    def handler(signum, frame) -> None:
        if _requested.is_set():
            raise KeyboardInterrupt
        _requested.set()

    previous = signal.signal(signal.SIGINT, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
        _requested.clear()


def checked(items: Iterator, what: str) -> Iterator:
    """``items``, raising :class:`RunInterrupted` before the next item once a stop was requested."""
    for n, item in enumerate(items):
        if _requested.is_set():
            raise RunInterrupted(f"interrupted while {what} (after {n} frames); nothing written")
        yield item
