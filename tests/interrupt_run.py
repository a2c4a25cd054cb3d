"""`semmap run` (its real entry point) on a dataset whose frame K sends a signal to this very process: SIGINT as a
Ctrl-C would, or SIGKILL as ``kill -9`` would. Used by tests/test_crash_safety.py:

    python tests/interrupt_run.py INT|KILL K DATASET --out OUT [semmap run options]
"""

from __future__ import annotations

import os
import signal
import sys


class _SignalAt:
    """A dataset that signals this process when it is about to hand out the frame of index ``at``."""

    def __init__(self, dataset, at: int, sig: int) -> None:
        self._dataset, self._at, self._sig = dataset, at, sig

    def __getattr__(self, name):
        return getattr(self._dataset, name)

    def __len__(self) -> int:
        return len(self._dataset)

    def __iter__(self):
        for frame in self._dataset:
            if frame.index == self._at:
                os.kill(os.getpid(), self._sig)
            yield frame


def main() -> None:
    import semmap.datasets as datasets
    from semmap.cli import main as semmap_main

    sig = {"INT": signal.SIGINT, "KILL": signal.SIGKILL}[sys.argv[1]]
    at = int(sys.argv[2])
    open_dataset = datasets.open_dataset
    datasets.open_dataset = lambda *a, **k: _SignalAt(open_dataset(*a, **k), at, sig)
    sys.argv = ["semmap", "run", *sys.argv[3:]]
    semmap_main()


if __name__ == "__main__":
    main()
