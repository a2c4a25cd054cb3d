"""Test configuration: make tests/ importable (naive.py, helpers.py), locate ../shared, and, under xdist, compile
the numba kernels once before the workers start."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))

# OpenMP threads (numba's kernels, torch) sleep while they wait for work instead of spinning: spinning threads
# count against the core the other xdist worker needs, and the suite took six times the CPU of its work in numba's
# parallel kernels (60 frames of dense SLAM: 11.4 CPU-s spinning, 1.7 passive, the same poses). Set before
# anything loads an OpenMP runtime; the CLI runs the tests start inherit it.
os.environ.setdefault("OMP_WAIT_POLICY", "passive")

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
SEVEN_SCENES = SHARED / "data" / "7scenes-redkitchen"
WARM_KERNELS = Path(__file__).parent / "warm_kernels.py"


@pytest.fixture
def seven_scenes() -> Path:
    if not SEVEN_SCENES.is_dir():
        pytest.skip("../shared/data/7scenes-redkitchen is not present")
    return SEVEN_SCENES


def pytest_sessionstart(session: pytest.Session) -> None:
    """In the xdist controller (``make test``: ``-n 2``), compile the map kernels into numba's shared cache, both
    halves at once, before the workers start: otherwise each worker compiles the same kernels at the same time, on
    a fresh clone, and the second copy costs a core for minutes. Workers and plain ``pytest`` runs skip this."""
    config = session.config
    if hasattr(config, "workerinput") or not getattr(config.option, "numprocesses", None):
        return
    from warm_kernels import PARTS

    t = time.perf_counter()
    runs = [subprocess.Popen([sys.executable, str(WARM_KERNELS), part], stdout=subprocess.PIPE,
                             stderr=subprocess.STDOUT, text=True) for part in PARTS]
    outputs = [run.communicate()[0] for run in runs]
    reporter = config.pluginmanager.get_plugin("terminalreporter")
    failed = [out for run, out in zip(runs, outputs, strict=True) if run.returncode != 0]
    if reporter is not None:  # a failure here is only slower: the tests meet the same error and report it
        reporter.write_line(f"numba kernels compiled or loaded in {time.perf_counter() - t:.1f} s"
                            + (f"; the warm-up failed:\n{failed[0]}" if failed else ""))
