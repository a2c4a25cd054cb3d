"""numba kernel of the connected-components instance source: which components of one class continue behind an
occluder (a table seen on both sides of a chair's back)."""

from __future__ import annotations

import numba as nb
import numpy as np


@nb.njit(cache=True)
def occluded_links(comp: np.ndarray, cls: np.ndarray, depth: np.ndarray, max_gap: int, rel: float, floor: float,
                   slope: float, fx: float) -> tuple[np.ndarray, np.ndarray]:
    """Row and column crossings between components of one class: ``(links, apart)``, each (P, 2) int64 pairs
    ``(a, b)`` with ``a < b``, one per crossing.

    Along every row (left to right) and column (top to bottom), after component ``a``'s last pixel come at most
    ``max_gap`` pixels of no component or of a component nearer than ``a``, then component ``b`` of ``a``'s
    class. A crossing is a link when the camera sees something nearer than ``a`` in the gap (at least one pixel
    with valid depth nearer by the jump threshold ``max(floor, rel * depth)``), nothing farther than either side
    by it, and ``b``'s depth continues ``a``'s: ``|d_a - d_b|`` at most the jump threshold plus ``slope`` times the
    hidden span (the gap's width at that depth, ``gap * d / fx`` metres). It is apart when the gap shows something
    farther than both sides by the jump threshold: the background between two things.

    ``comp`` (H, W) int32 component ids (0: none), ``cls`` (N + 1,) int64 class of each id, ``depth`` (H, W)
    float32 metres (0: invalid)."""
    H, W = comp.shape
    # a crossing needs a gap pixel before it: at most one per pixel
    links = np.empty((H * W + 1, 2), np.int64)
    apart = np.empty((H * W + 1, 2), np.int64)
    n_links = 0
    n_apart = 0
    for axis in range(2):
        lines = H if axis == 0 else W
        length = W if axis == 0 else H
        for line in range(lines):
            a = 0
            da = 0.0
            gap = 0
            nearer = 0
            gap_max = 0.0
            for i in range(length):
                v = line if axis == 0 else i
                u = i if axis == 0 else line
                c = comp[v, u]
                d = depth[v, u]
                if c == a and c > 0:  # still on a
                    if d > 0:
                        da = d
                    gap = 0
                    nearer = 0
                    gap_max = 0.0
                    continue
                if a > 0 and c > 0 and d > 0 and da > 0:
                    thr = max(floor, rel * min(da, d))
                    if cls[c] == cls[a] and gap > 0:
                        if gap_max > max(da, d) + thr:
                            apart[n_apart, 0] = min(a, c)
                            apart[n_apart, 1] = max(a, c)
                            n_apart += 1
                        elif nearer > 0 and abs(da - d) <= thr + slope * gap * min(da, d) / fx:
                            links[n_links, 0] = min(a, c)
                            links[n_links, 1] = max(a, c)
                            n_links += 1
                    elif d < da - thr and gap < max_gap:  # a nearer thing in front of a: part of the gap
                        gap += 1
                        nearer += 1
                        continue
                if c > 0:  # a new open surface
                    a = c
                    da = d
                    gap = 0
                    nearer = 0
                    gap_max = 0.0
                    continue
                if a == 0:
                    continue
                gap += 1
                if gap > max_gap:
                    a = 0
                    continue
                if d > 0:
                    if d < da - max(floor, rel * da):
                        nearer += 1
                    gap_max = max(gap_max, d)
    return links[:n_links], apart[:n_apart]
