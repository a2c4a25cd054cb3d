"""The yardstick of the octree benchmark: an occupancy-only OctoMap insertion in numba, as lean as it gets.

No colour, no semantics, no sharding, no attribute rows: one plain open-addressing hash map (packed key ->
float32 log-odds, linear probing, doubled at half load) and one straight pass per step over a scan:

1. keys of the points and their bounding box (parallel chunks);
2. voxel filter: the first point of each endpoint cell marks it "hit" in a byte grid over the box (serial);
3. rays from the origin to the endpoint cell centres mark untouched cells "free" (parallel, OctoMap's
   ``computeRayKeys`` via ``maps._keys.trace_ray``);
4. free cells read back in grid order, grid reset on the way (serial);
5. miss updates for the free cells, then hit updates for the endpoint cells (serial).

The same discretised insertion as ``insertPointCloud(discretize=True)`` (no max range), so its cells agree
with OctoMap's and with ``SemanticOctoMap``'s exactly; ``bench_octree_vs_octomap.py`` times the full semantic
insertion against it.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from semmap.keys import KEY_LIMIT
from semmap.maps._keys import EMPTY_KEY, coord_to_key, key_to_coord, pack_key, trace_ray

_MIN_CAPACITY = 1 << 16
_HASH_MULT = np.uint64(0x9E3779B97F4A7C15)


@nb.njit(cache=True, inline="always")
def _slot(k: np.int64, mask: np.int64) -> np.int64:
    return np.int64((np.uint64(k) * _HASH_MULT) >> np.uint64(20)) & mask


@nb.njit(cache=True)
def _update(table_keys, table_lo, k, delta, lo_clamp, hi_clamp) -> bool:
    """Add ``delta`` to the log-odds of ``k`` (0 when new), clamped; True when the key was new."""
    mask = table_keys.shape[0] - 1
    s = _slot(k, mask)
    while True:
        v = table_keys[s]
        if v == k:
            x = table_lo[s] + delta
            table_lo[s] = min(max(x, lo_clamp), hi_clamp)
            return False
        if v == EMPTY_KEY:
            table_keys[s] = k
            table_lo[s] = min(max(np.float32(0.0) + delta, lo_clamp), hi_clamp)
            return True
        s = (s + 1) & mask


@nb.njit(cache=True)
def _rehash(old_keys, old_lo, new_keys, new_lo) -> None:
    mask = new_keys.shape[0] - 1
    for i in range(old_keys.shape[0]):
        k = old_keys[i]
        if k != EMPTY_KEY:
            s = _slot(k, mask)
            while new_keys[s] != EMPTY_KEY:
                s = (s + 1) & mask
            new_keys[s] = k
            new_lo[s] = old_lo[i]


@nb.njit(cache=True, parallel=True)
def _keys_and_box(points, res_factor, n_chunks, keys, valid):
    n = points.shape[0]
    boxes = np.empty((n_chunks, 6), np.int64)
    chunk = (n + n_chunks - 1) // n_chunks
    for c in nb.prange(n_chunks):
        lox = loy = loz = np.int64(KEY_LIMIT)
        hix = hiy = hiz = np.int64(-1)
        for i in range(c * chunk, min(n, (c + 1) * chunk)):
            x, y, z = np.float32(points[i, 0]), np.float32(points[i, 1]), np.float32(points[i, 2])
            ok = math.isfinite(x) and math.isfinite(y) and math.isfinite(z)
            kx = coord_to_key(x, res_factor) if ok else np.int64(0)
            ky = coord_to_key(y, res_factor) if ok else np.int64(0)
            kz = coord_to_key(z, res_factor) if ok else np.int64(0)
            ok = ok and 0 <= kx < KEY_LIMIT and 0 <= ky < KEY_LIMIT and 0 <= kz < KEY_LIMIT
            keys[i, 0], keys[i, 1], keys[i, 2] = kx, ky, kz
            valid[i] = ok
            if ok:
                lox, hix = min(lox, kx), max(hix, kx)
                loy, hiy = min(loy, ky), max(hiy, ky)
                loz, hiz = min(loz, kz), max(hiz, kz)
        boxes[c, 0], boxes[c, 1], boxes[c, 2] = lox, loy, loz
        boxes[c, 3], boxes[c, 4], boxes[c, 5] = hix, hiy, hiz
    return boxes


@nb.njit(cache=True)
def _endpoints(keys, valid, grid, g0x, g0y, g0z, gny, gnz, resolution, out_packed, out_targets) -> int:
    m = 0
    for i in range(valid.shape[0]):
        if not valid[i]:
            continue
        idx = ((keys[i, 0] - g0x) * gny + keys[i, 1] - g0y) * gnz + keys[i, 2] - g0z
        if grid[idx] == 0:
            grid[idx] = 2
            out_packed[m] = pack_key(keys[i, 0], keys[i, 1], keys[i, 2])
            for a in range(3):
                out_targets[m, a] = np.float32(key_to_coord(keys[i, a], resolution))
            m += 1
    return m


@nb.njit(cache=True, parallel=True)
def _rays(origin, targets, m, resolution, res_factor, grid, g0x, g0y, g0z, gny, gnz, n_chunks) -> None:
    chunk = (m + n_chunks - 1) // n_chunks
    dummy = np.empty((0, 3), np.int64)
    for c in nb.prange(n_chunks):
        for j in range(c * chunk, min(m, (c + 1) * chunk)):
            trace_ray(origin[0], origin[1], origin[2], targets[j, 0], targets[j, 1], targets[j, 2],
                      resolution, res_factor, grid, g0x, g0y, g0z, gny, gnz, dummy, False)


@nb.njit(cache=True)
def _free_cells(grid, g0x, g0y, g0z, gnx, gny, gnz, out):
    """Packed keys of the cells marked free, in grid order (``out`` grown when full), and their count; resets
    every mark (hits too)."""
    plane = gny * gnz
    words = grid[: gnx * plane].view(np.uint64)
    n = 0
    for w in range(words.shape[0]):
        if words[w] == 0:
            continue
        for b in range(8):
            r = w * 8 + b
            if grid[r] == 1:
                if n == out.shape[0]:
                    bigger = np.empty(2 * n, np.int64)
                    bigger[:n] = out
                    out = bigger
                x = r // plane
                y = (r - x * plane) // gnz
                out[n] = pack_key(g0x + x, g0y + y, g0z + r - x * plane - y * gnz)
                n += 1
        words[w] = 0
    return out, n


@nb.njit(cache=True)
def _apply(table_keys, table_lo, free, n_free, hits, n_hits, miss, hit, lo_clamp, hi_clamp) -> int:
    new = 0
    for i in range(n_free):
        new += _update(table_keys, table_lo, free[i], miss, lo_clamp, hi_clamp)
    for i in range(n_hits):
        new += _update(table_keys, table_lo, hits[i], hit, lo_clamp, hi_clamp)
    return new


class OccupancyReference:
    """Occupancy-only OctoMap insertion (``insertPointCloud(discretize=True)``, no max range): the benchmark's
    yardstick for what the occupancy part of an insertion costs at best."""

    def __init__(self, resolution: float, *, hit: float = 0.7, miss: float = 0.4, clamp_min: float = 0.1192,
                 clamp_max: float = 0.971, threads: int | None = None):
        self.resolution = float(resolution)
        lo = [np.float32(math.log(p / (1 - p))) for p in (hit, miss, clamp_min, clamp_max)]
        self._hit, self._miss, self._min, self._max = lo
        self._keys = np.full(_MIN_CAPACITY, EMPTY_KEY, np.int64)
        self._lo = np.zeros(_MIN_CAPACITY, np.float32)
        self._n = 0
        self._grid = np.zeros(0, np.uint8)
        self._threads = threads or nb.get_num_threads()
        self._buf_n = 0
        self._free = np.empty(1 << 16, np.int64)

    def _buffers(self, n: int) -> None:
        if self._buf_n < n:
            self._buf_n = int(n * 1.25)
            self._pkeys = np.empty((self._buf_n, 3), np.int32)
            self._valid = np.empty(self._buf_n, np.bool_)
            self._hits = np.empty(self._buf_n, np.int64)
            self._targets = np.empty((self._buf_n, 3), np.float32)

    def insert_points(self, points: np.ndarray, origin: np.ndarray) -> None:
        """Insert one scan of world points (N, 3) seen from ``origin`` (3,) (inside the key range)."""
        pts = np.ascontiguousarray(points)
        org = np.asarray(origin, np.float32)
        self._buffers(len(pts))
        keys, valid = self._pkeys[: len(pts)], self._valid[: len(pts)]
        boxes = _keys_and_box(pts, 1.0 / self.resolution, self._threads, keys, valid)
        okey = np.floor(org.astype(np.float64) / self.resolution).astype(np.int64) + KEY_LIMIT // 2
        lo = np.minimum(boxes[:, :3].min(axis=0), okey) - 1
        hi = np.maximum(boxes[:, 3:].max(axis=0), okey) + 1
        gnx, gny, gnz = (int(v) for v in hi - lo + 1)
        gnz += -gnz % 8
        if self._grid.shape[0] < gnx * gny * gnz:
            self._grid = np.zeros(int(gnx * gny * gnz * 1.25), np.uint8)
        g0x, g0y, g0z = (int(v) for v in lo)
        m = _endpoints(keys, valid, self._grid, g0x, g0y, g0z, gny, gnz, self.resolution, self._hits,
                       self._targets)
        _rays(org, self._targets, m, self.resolution, 1.0 / self.resolution, self._grid, g0x, g0y, g0z, gny, gnz,
              self._threads)
        self._free, n_free = _free_cells(self._grid, g0x, g0y, g0z, gnx, gny, gnz, self._free)
        while 2 * (self._n + n_free + m) > self._keys.shape[0]:  # keep the load under one half
            keys2 = np.full(2 * self._keys.shape[0], EMPTY_KEY, np.int64)
            lo2 = np.zeros(keys2.shape[0], np.float32)
            _rehash(self._keys, self._lo, keys2, lo2)
            self._keys, self._lo = keys2, lo2
        self._n += _apply(self._keys, self._lo, self._free, n_free, self._hits, m, self._miss, self._hit,
                          self._min, self._max)

    def cells(self) -> tuple[np.ndarray, np.ndarray]:
        """(packed keys, log-odds) of every known cell, sorted by key."""
        used = np.flatnonzero(self._keys != EMPTY_KEY)
        order = np.argsort(self._keys[used])
        return self._keys[used][order], self._lo[used][order]
