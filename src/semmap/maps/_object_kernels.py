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


@nb.njit(cache=True)
def sorted_intersection_size(a: np.ndarray, b: np.ndarray) -> int:
    """How many keys two ascending arrays of unique int64 keys share: one merge pass, no sort."""
    i = j = n = 0
    while i < len(a) and j < len(b):
        if a[i] < b[j]:
            i += 1
        elif a[i] > b[j]:
            j += 1
        else:
            n += 1
            i += 1
            j += 1
    return n


@nb.njit(cache=True)
def sorted_union(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The ascending union of two ascending arrays of unique int64 keys (``np.union1d`` without its sort)."""
    out = np.empty(len(a) + len(b) - sorted_intersection_size(a, b), np.int64)
    i = j = n = 0
    while i < len(a) or j < len(b):
        if j == len(b) or (i < len(a) and a[i] < b[j]):
            out[n] = a[i]
            i += 1
        elif i == len(a) or b[j] < a[i]:
            out[n] = b[j]
            j += 1
        else:
            out[n] = a[i]
            i += 1
            j += 1
        n += 1
    return out


@nb.njit(cache=True)
def merge_cells(keys: np.ndarray, points: np.ndarray, colors: np.ndarray, new_keys: np.ndarray,
                new_points: np.ndarray, new_colors: np.ndarray):
    """Insert the cells of ``new_keys`` an object does not have yet into its ascending ``keys`` (cells it has keep
    their point and colour). Returns the merged keys, points and colours and the sum of the points added."""
    m = len(keys) + len(new_keys) - sorted_intersection_size(keys, new_keys)
    out_k = np.empty(m, np.int64)
    out_p = np.empty((m, 3), points.dtype)
    out_c = np.empty((m, 3), colors.dtype)
    added = np.zeros(3)
    i = j = n = 0
    while i < len(keys) or j < len(new_keys):
        if j == len(new_keys) or (i < len(keys) and keys[i] <= new_keys[j]):
            if j < len(new_keys) and keys[i] == new_keys[j]:
                j += 1  # the object has this cell: it keeps its point
            out_k[n] = keys[i]
            out_p[n] = points[i]
            out_c[n] = colors[i]
            i += 1
        else:
            out_k[n] = new_keys[j]
            out_p[n] = new_points[j]
            out_c[n] = new_colors[j]
            for a in range(3):
                added[a] += new_points[j, a]
            j += 1
        n += 1
    return out_k, out_p, out_c, added


@nb.njit(cache=True)
def cells_per_segment(points: np.ndarray, bounds: np.ndarray, cell: float, key_bits: int):
    """Sorted unique packed keys of the ``cell``-sized cells holding each segment's points (segment ``k`` is
    ``points[bounds[k]:bounds[k + 1]]``), concatenated, and where each segment's keys start. Keys pack the three
    cell coordinates as ``key_bits``-bit fields offset by half their range (``objects.pack_cells``). The third
    value is False when a coordinate fell outside that range (the keys are then not to be used)."""
    n = len(bounds) - 1
    offset = 1 << (key_bits - 1)
    keys = np.empty(len(points), np.int64)
    out_bounds = np.zeros(n + 1, np.int64)
    m = 0
    ok = True
    top = 1 << key_bits
    for k in range(n):
        start = bounds[k]
        seg = np.empty(bounds[k + 1] - start, np.int64)
        for i in range(len(seg)):
            c0 = np.int64(np.floor(points[start + i, 0] / cell)) + offset
            c1 = np.int64(np.floor(points[start + i, 1] / cell)) + offset
            c2 = np.int64(np.floor(points[start + i, 2] / cell)) + offset
            ok = ok and 0 <= c0 < top and 0 <= c1 < top and 0 <= c2 < top
            seg[i] = (c0 << (2 * key_bits)) | (c1 << key_bits) | c2
        seg.sort()
        for i in range(len(seg)):
            if i == 0 or seg[i] != seg[i - 1]:
                keys[m] = seg[i]
                m += 1
        out_bounds[k + 1] = m
    return keys[:m].copy(), out_bounds, ok


@nb.njit(cache=True)
def segment_bounds_and_mean(points: np.ndarray, bounds: np.ndarray):
    """Per segment ``points[bounds[k]:bounds[k + 1]]``: the mean, minimum and maximum point, (n, 3) each."""
    n = len(bounds) - 1
    mean = np.zeros((n, 3))
    lo = np.full((n, 3), np.inf)
    hi = np.full((n, 3), -np.inf)
    for k in range(n):
        for i in range(bounds[k], bounds[k + 1]):
            for a in range(3):
                v = points[i, a]
                mean[k, a] += v
                lo[k, a] = min(lo[k, a], v)
                hi[k, a] = max(hi[k, a], v)
        if bounds[k + 1] > bounds[k]:
            for a in range(3):
                mean[k, a] /= bounds[k + 1] - bounds[k]
    return mean, lo, hi
