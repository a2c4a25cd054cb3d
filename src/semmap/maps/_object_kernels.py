"""numba kernels of the object map: per-point mean neighbour distance on the pixel grid of a depth image."""

from __future__ import annotations

import numba as nb
import numpy as np


@nb.njit(cache=True)
def grid_neighbour_distances(ids: np.ndarray, x: np.ndarray, y: np.ndarray, z: np.ndarray) -> np.ndarray:
    """(H, W) mean 3D distance from each labelled pixel's point to the points of its (up to 8) grid neighbours
    with the same label; ``inf`` where a pixel has no such neighbour, ``nan`` where it is unlabelled (label 0).

    ``ids`` (H, W) int32 labels, ``x, y, z`` (H, W) float64 camera-frame coordinates of each pixel's point."""
    H, W = ids.shape
    out = np.full((H, W), np.nan)
    for v in range(H):
        for u in range(W):
            k = ids[v, u]
            if k == 0:
                continue
            total = 0.0
            n = 0
            for dv in range(-1, 2):
                vv = v + dv
                if vv < 0 or vv >= H:
                    continue
                for du in range(-1, 2):
                    uu = u + du
                    if (dv == 0 and du == 0) or uu < 0 or uu >= W or ids[vv, uu] != k:
                        continue
                    ex = x[vv, uu] - x[v, u]
                    ey = y[vv, uu] - y[v, u]
                    ez = z[vv, uu] - z[v, u]
                    total += np.sqrt(ex * ex + ey * ey + ez * ez)
                    n += 1
            out[v, u] = total / n if n > 0 else np.inf
    return out
