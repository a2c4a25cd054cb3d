"""Compile (or load) semmap's numba kernels into the shared cache: ``python tests/warm_kernels.py PART``.

``conftest.py`` runs the parts side by side in the xdist controller before the workers start, so a fresh clone
compiles each kernel once, on both cores, and every worker then loads it from the cache (``semmap/__init__.py``
keys the cache folder by the kernels' sources, so the controller and the workers share one folder).
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable


def _octomap() -> None:
    from semmap.maps.registry import MAPS

    MAPS["octomap"].compile_kernels()


def _grids() -> None:
    from semmap.localization._kernels import compile_kernels as localization_kernels
    from semmap.maps.registry import MAPS

    MAPS["voxelgrid"].compile_kernels()
    MAPS["tsdf"].compile_kernels()
    localization_kernels()


#: The parts, about equal in compile time, one process each.
PARTS: dict[str, Callable[[], None]] = {"octomap": _octomap, "grids": _grids}


def main(names: list[str]) -> None:
    for name in names:
        t = time.perf_counter()
        PARTS[name]()
        print(f"{name}: {time.perf_counter() - t:.1f} s", flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])
