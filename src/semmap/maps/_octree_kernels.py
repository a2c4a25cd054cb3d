"""Per-frame insertion kernels of the semantic OctoMap (numba, flat arrays).

One scan is inserted as OctoMap's ``insertPointCloud(discretize=True)`` does it, in five passes:

1. ``point_keys``: keys of all endpoints and their bounding box (parallel, one chunk per thread);
2. ``scan_endpoints``: voxel filter and ray targets in one serial pass: the first point of each endpoint cell
   represents it; its cell is marked "hit" (2) in a temporary byte grid over the scan's bounding box, and its
   packed key and ray target (the cell centre, or the max-range point) are recorded;
3. ``cast_rays``: rays from the origin to every target mark untouched cells "free" (1); hits are never
   overwritten, so "occupied wins" needs no set difference and threads write only the value 1, so they need no
   atomics;
4. ``collect_free``: free cells gathered in grid order, 8 bytes of grid at a time; the grid is reset on the way;
5. ``update_cells`` (misses, then hits), ``assign_rows`` and ``update_attributes``: log-odds updates with the
   cells split by shard between threads (disjoint shards need no atomics), attribute rows of first hits in cell
   order, then colour running means and label fusion per row (the fusion dispatcher, ``fusion/dispatch.py``).

Passes with enough work run on every thread, passes with little on one (``*_PARALLEL_MIN``).  The table and
attribute passes prefetch the cache lines of the item ``PREFETCH_AHEAD`` places ahead: the table is far bigger
than the caches, and cells in grid order fall into its z-groups several at a time, so without the hint the CPU
waits for one group's miss after another.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from semmap.fusion.dispatch import GENERIC, TOPK_CODE, finish_voxel, fuse_measurement, new_scratch
from semmap.maps._hashtable import find_or_insert, find_slot, prefetch_home, shard_of
from semmap.maps._keys import KEY_LIMIT, coord_to_key, key_to_coord, pack_key, trace_ray
from semmap.maps._prefetch import prefetch

#: Items from which a pass runs on every thread: about 0.2 ms of work each (rays of 50-100 cells, table
#: updates, attribute rows with fusion); below that waking the other threads costs about what it saves, and far
#: more when other processes hold the cores.
RAYS_PARALLEL_MIN = 1024
CELLS_PARALLEL_MIN = 8192
ROWS_PARALLEL_MIN = 2048
#: Cells ahead whose table lines a table pass prefetches (measured: 9.5 -> 6.0 ms for 340k cells at 2 cm).
PREFETCH_AHEAD = 32


@nb.njit(cache=True, parallel=True, nogil=True)
def point_keys(points: np.ndarray, res_factor: float, n_chunks: int, keys: np.ndarray, valid: np.ndarray):
    """Fill ``keys`` (N, 3) int32 with the keys of points (float32 or float64, taken as float32) and ``valid``
    (N,) with "finite and inside the key range"; returns per-chunk bounding boxes (n_chunks, 6) = (min xyz,
    max xyz) of the valid keys.  The output arrays are the caller's, reused between scans (no page faults)."""
    n = points.shape[0]
    boxes = np.empty((n_chunks, 6), np.int64)
    chunk = (n + n_chunks - 1) // n_chunks
    for c in nb.prange(n_chunks):
        # scalar bounds (registers, not arrays) for the tight loop
        lox = loy = loz = np.int64(KEY_LIMIT)
        hix = hiy = hiz = np.int64(-1)
        for i in range(c * chunk, min(n, (c + 1) * chunk)):
            x = np.float32(points[i, 0])  # OctoMap's point3d is float32 whatever the input
            y = np.float32(points[i, 1])
            z = np.float32(points[i, 2])
            ok = math.isfinite(x) and math.isfinite(y) and math.isfinite(z)
            kx = coord_to_key(x, res_factor) if ok else np.int64(0)
            ky = coord_to_key(y, res_factor) if ok else np.int64(0)
            kz = coord_to_key(z, res_factor) if ok else np.int64(0)
            ok = ok and 0 <= kx < KEY_LIMIT and 0 <= ky < KEY_LIMIT and 0 <= kz < KEY_LIMIT
            keys[i, 0] = kx
            keys[i, 1] = ky
            keys[i, 2] = kz
            valid[i] = ok
            if ok:
                lox, hix = min(lox, kx), max(hix, kx)
                loy, hiy = min(loy, ky), max(hiy, ky)
                loz, hiz = min(loz, kz), max(hiz, kz)
        boxes[c, 0], boxes[c, 1], boxes[c, 2] = lox, loy, loz
        boxes[c, 3], boxes[c, 4], boxes[c, 5] = hix, hiy, hiz
    return boxes


@nb.njit(cache=True, inline="always")
def _target(kx, ky, kz, ox: np.float32, oy: np.float32, oz: np.float32, resolution: float, max_range: float,
            targets: np.ndarray, j: int) -> bool:
    """Ray target of an endpoint cell into ``targets[j]``; True for a hit (centre within ``max_range``).

    Targets are the cell centres (discretised insertion).  A centre farther than ``max_range`` (>= 0) becomes
    ``origin + dir * max_range`` in float32 arithmetic, as OctoMap's computeUpdate does."""
    cx = np.float32(key_to_coord(kx, resolution))
    cy = np.float32(key_to_coord(ky, resolution))
    cz = np.float32(key_to_coord(kz, resolution))
    dx = cx - ox
    dy = cy - oy
    dz = cz - oz
    dist = math.sqrt(np.float64(dx * dx + dy * dy + dz * dz))
    if max_range < 0.0 or dist <= max_range:
        targets[j, 0] = cx
        targets[j, 1] = cy
        targets[j, 2] = cz
        return True
    inv = np.float32(dist)
    mr = np.float32(max_range)
    targets[j, 0] = ox + (dx / inv) * mr
    targets[j, 1] = oy + (dy / inv) * mr
    targets[j, 2] = oz + (dz / inv) * mr
    return False


@nb.njit(cache=True, nogil=True)
def scan_endpoints(keys: np.ndarray, valid: np.ndarray, grid: np.ndarray,
                   g0x: int, g0y: int, g0z: int, gnx: int, gny: int, gnz: int,
                   origin: np.ndarray, resolution: float, max_range: float,
                   first: np.ndarray, packed: np.ndarray, targets: np.ndarray, hit: np.ndarray) -> int:
    """Voxel filter and ray targets of one scan; returns the number M of endpoint cells inside the grid.

    For each such cell, in input order of its first point: that point's index (``first``), the packed key, the
    ray target (M, 3) float32 and whether it is a hit (``hit``: within max range).  Hit cells are marked 2 in the
    grid; cells of max-range readings are left unmarked (they have no occupied end).  Points beyond the
    range-limited grid are skipped (max-range readings, handled by the caller).  Output arrays hold N entries.
    """
    ox, oy, oz = origin[0], origin[1], origin[2]
    m = 0
    for i in range(valid.shape[0]):
        if not valid[i]:
            continue
        kx, ky, kz = keys[i, 0], keys[i, 1], keys[i, 2]
        x, y, z = kx - g0x, ky - g0y, kz - g0z
        if x < 0 or y < 0 or z < 0 or x >= gnx or y >= gny or z >= gnz:
            continue
        idx = (x * gny + y) * gnz + z
        if grid[idx] != 0:
            continue
        grid[idx] = 2
        first[m] = i
        packed[m] = pack_key(kx, ky, kz)
        hit[m] = _target(kx, ky, kz, ox, oy, oz, resolution, max_range, targets, m)
        m += 1
    if max_range >= 0.0:  # unmark max-range cells only now: the filter above needed their marks
        for j in range(m):
            if not hit[j]:
                i = first[j]
                grid[((keys[i, 0] - g0x) * gny + keys[i, 1] - g0y) * gnz + keys[i, 2] - g0z] = 0
    return m


@nb.njit(cache=True, nogil=True)
def far_targets(keys: np.ndarray, idx: np.ndarray, origin: np.ndarray, resolution: float,
                max_range: float) -> np.ndarray:
    """Ray targets (M, 3) float32 of endpoint cells beyond the range-limited grid (all max-range readings)."""
    targets = np.empty((idx.shape[0], 3), np.float32)
    for j in range(idx.shape[0]):
        i = idx[j]
        _target(keys[i, 0], keys[i, 1], keys[i, 2], origin[0], origin[1], origin[2], resolution, max_range,
                targets, j)
    return targets


@nb.njit(cache=True, inline="always")
def _trace_chunk(origin, targets, lo: int, hi: int, resolution, res_factor, grid, g0x, g0y, g0z, gny, gnz) -> int:
    dummy = np.empty((0, 3), np.int64)
    s = 0
    for j in range(lo, hi):
        r = trace_ray(origin[0], origin[1], origin[2], targets[j, 0], targets[j, 1], targets[j, 2], resolution,
                      res_factor, grid, g0x, g0y, g0z, gny, gnz, dummy, False)
        if r > 0:
            s += r
    return s


@nb.njit(cache=True, parallel=True, nogil=True)
def _cast_rays_parallel(origin, targets, resolution, res_factor, grid, g0x, g0y, g0z, gny, gnz, n_chunks) -> int:
    m = targets.shape[0]
    chunk = (m + n_chunks - 1) // n_chunks
    steps = np.zeros(n_chunks, np.int64)
    for c in nb.prange(n_chunks):
        steps[c] = _trace_chunk(origin, targets, c * chunk, min(m, (c + 1) * chunk), resolution, res_factor,
                                grid, g0x, g0y, g0z, gny, gnz)
    return steps.sum()


@nb.njit(cache=True, nogil=True)
def _cast_rays_serial(origin, targets, resolution, res_factor, grid, g0x, g0y, g0z, gny, gnz) -> int:
    return _trace_chunk(origin, targets, 0, targets.shape[0], resolution, res_factor, grid, g0x, g0y, g0z, gny, gnz)


def cast_rays(origin: np.ndarray, targets: np.ndarray, resolution: float, res_factor: float, grid: np.ndarray,
              g0x: int, g0y: int, g0z: int, gny: int, gnz: int, n_threads: int) -> int:
    """Mark the free cells of every ray origin→target in the grid; returns the number of cells visited."""
    if n_threads > 1 and targets.shape[0] >= RAYS_PARALLEL_MIN:
        return int(_cast_rays_parallel(origin, targets, resolution, res_factor, grid, g0x, g0y, g0z, gny, gnz,
                                       n_threads))
    return int(_cast_rays_serial(origin, targets, resolution, res_factor, grid, g0x, g0y, g0z, gny, gnz))


@nb.njit(cache=True, nogil=True)
def collect_free(grid: np.ndarray, n_cells: int, g0x: int, g0y: int, g0z: int, gny: int, gnz: int,
                 out: np.ndarray):
    """Packed keys of the cells marked free in the first ``n_cells`` bytes of the grid, in grid order, read 8
    bytes at a time (``out`` is grown when full), and their count; every mark is reset (hits too).
    ``n_cells`` is a multiple of 8."""
    plane = gny * gnz
    words = grid[:n_cells].view(np.uint64)
    n = 0
    for w in range(n_cells // 8):
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


@nb.njit(cache=True, inline="always")
def _update_part(cells, n: int, part: int, n_parts: int, start: int, keys, logodds, attr, counts, shard_cap: int,
                 delta: np.float32, clamp_lo: np.float32, clamp_hi: np.float32, fill_limit: int, slots) -> int:
    """Log-odds update of the cells whose shard is ``part`` modulo ``n_parts`` (so parts touch disjoint
    shards), from ``start`` on; the slot of cell i goes to ``slots[i]`` when ``slots`` has room.  Returns n when
    done, else the index where a shard was about to fill past ``fill_limit``."""
    record = slots.shape[0] >= n
    for i in range(start, n):
        if i + PREFETCH_AHEAD < n:  # the table is far bigger than the caches: start the misses early
            ahead = cells[i + PREFETCH_AHEAD]
            sa = shard_of(ahead)
            if sa % n_parts == part:
                prefetch_home(keys, logodds, sa, shard_cap, ahead)
        k = cells[i]
        sh = shard_of(k)
        if sh % n_parts != part:
            continue
        if counts[sh] >= fill_limit and find_slot(keys, shard_cap, k) < 0:
            return i
        s = find_or_insert(keys, logodds, attr, counts, sh, shard_cap, k)
        if s < 0:  # lane full
            return i
        v = logodds[s] + delta
        logodds[s] = clamp_lo if v < clamp_lo else (clamp_hi if v > clamp_hi else v)
        if record:
            slots[i] = s
    return n


@nb.njit(cache=True, parallel=True, nogil=True)
def _update_parallel(cells, n, progress, keys, logodds, attr, counts, shard_cap, delta, clamp_lo, clamp_hi,
                     fill_limit, slots) -> None:
    n_parts = progress.shape[0]
    for part in nb.prange(n_parts):
        progress[part] = _update_part(cells, n, part, n_parts, progress[part], keys, logodds, attr, counts,
                                      shard_cap, delta, clamp_lo, clamp_hi, fill_limit, slots)


@nb.njit(cache=True, nogil=True)
def _update_serial(cells, n, progress, keys, logodds, attr, counts, shard_cap, delta, clamp_lo, clamp_hi,
                   fill_limit, slots) -> None:
    n_parts = progress.shape[0]
    for part in range(n_parts):
        progress[part] = _update_part(cells, n, part, n_parts, progress[part], keys, logodds, attr, counts,
                                      shard_cap, delta, clamp_lo, clamp_hi, fill_limit, slots)


def update_cells(cells: np.ndarray, n: int, progress: np.ndarray, keys: np.ndarray, logodds: np.ndarray,
                 attr: np.ndarray, counts: np.ndarray, shard_cap: int, delta: np.float32, clamp_lo: np.float32,
                 clamp_hi: np.float32, fill_limit: int, slots: np.ndarray) -> bool:
    """Add ``delta`` to the log-odds of the first ``n`` packed keys ``cells`` (each at most once; new cells start
    at 0), clamped to [clamp_lo, clamp_hi], recording slots in ``slots`` unless it is empty.  The cells are
    split by shard into ``len(progress)`` parts run in parallel (disjoint shards: no atomics), or one after the
    other for few cells.  ``progress[p]`` is where part p resumes; returns False when a shard stopped before
    filling past ``fill_limit``: grow the table and call again."""
    args = (cells, n, progress, keys, logodds, attr, counts, shard_cap, delta, clamp_lo, clamp_hi, fill_limit,
            slots)
    if progress.shape[0] > 1 and n >= CELLS_PARALLEL_MIN:
        _update_parallel(*args)
    else:
        _update_serial(*args)
    return bool((progress >= n).all())


@nb.njit(cache=True, nogil=True)
def assign_rows(attr: np.ndarray, slots: np.ndarray, hit: np.ndarray, n_attr: int, rows: np.ndarray) -> int:
    """Attribute row of every hit cell (a first hit gets the next free row, in cell order) into ``rows`` (-1 for
    max-range cells); returns the new row count."""
    for j in range(slots.shape[0]):
        if not hit[j]:
            rows[j] = -1
            continue
        s = slots[j]
        if attr[s] < 0:
            attr[s] = n_attr
            n_attr += 1
        rows[j] = attr[s]
    return n_attr


@nb.njit(cache=True, inline="always")
def _attribute_chunk(rows, point_index, lo: int, hi: int, colors, has_colors: bool, sem_labels, sem_probs,
                     has_semantics: bool, rgb, rgb_count, map_labels, map_probs, code, update, finish, params) -> None:
    if code == TOPK_CODE:  # the rule's test hoisted out of the loop (see fusion.dispatch.fuse_measurement)
        _attribute_rows(rows, point_index, lo, hi, colors, has_colors, sem_labels, sem_probs, has_semantics, rgb,
                        rgb_count, map_labels, map_probs, False, TOPK_CODE, update, finish, params)
    elif code == GENERIC:
        _attribute_rows(rows, point_index, lo, hi, colors, has_colors, sem_labels, sem_probs, has_semantics, rgb,
                        rgb_count, map_labels, map_probs, True, code, update, finish, params)
    else:
        _attribute_rows(rows, point_index, lo, hi, colors, has_colors, sem_labels, sem_probs, has_semantics, rgb,
                        rgb_count, map_labels, map_probs, False, code, update, finish, params)


@nb.njit(cache=True, inline="always")
def _attribute_rows(rows, point_index, lo: int, hi: int, colors, has_colors: bool, sem_labels, sem_probs,
                    has_semantics: bool, rgb, rgb_count, map_labels, map_probs, generic: bool, code, update, finish,
                    params) -> None:
    si, sf = new_scratch()
    s = map_labels.shape[1]
    w = map_probs.shape[1]
    k = sem_labels.shape[1]
    for j in range(lo, hi):
        if j + PREFETCH_AHEAD < hi:  # rows and points are scattered: start their misses early
            ahead = rows[j + PREFETCH_AHEAD]
            pa = point_index[j + PREFETCH_AHEAD]
            if ahead >= 0:
                if has_colors:
                    prefetch(rgb, ahead * 3)
                    prefetch(colors, pa * 3)
                if has_semantics:
                    prefetch(map_labels, ahead * s)
                    prefetch(map_probs, ahead * w)
                    prefetch(sem_labels, pa * k)
                    prefetch(sem_probs, pa * k)
        a = rows[j]
        if a < 0:
            continue
        p = point_index[j]
        if has_colors:  # running mean (a slow moving average once the count saturates)
            n = np.int64(rgb_count[a]) + 1
            if n > 65535:
                n = 65535
            rgb_count[a] = n
            for ch in range(3):
                mean = np.float64(rgb[a, ch])
                rgb[a, ch] = np.uint8(np.int64(mean + (np.float64(colors[p, ch]) - mean) / n + 0.5))
        # one measurement per cell and scan (the voxel filter's first point)
        if has_semantics and fuse_measurement(generic, code, update, map_labels[a], map_probs[a], sem_labels[p],
                                              sem_probs[p], params, si, sf):
            finish_voxel(generic, code, finish, map_labels[a], map_probs[a], 1, params)


@nb.njit(cache=True, parallel=True, nogil=True)
def _attributes_parallel(rows, point_index, colors, has_colors, sem_labels, sem_probs, has_semantics,
                         rgb, rgb_count, map_labels, map_probs, code, update, finish, params, n_chunks) -> None:
    m = rows.shape[0]
    chunk = (m + n_chunks - 1) // n_chunks
    for c in nb.prange(n_chunks):
        _attribute_chunk(rows, point_index, c * chunk, min(m, (c + 1) * chunk), colors, has_colors, sem_labels,
                         sem_probs, has_semantics, rgb, rgb_count, map_labels, map_probs, code, update, finish,
                         params)


@nb.njit(cache=True, nogil=True)
def _attributes_serial(rows, point_index, colors, has_colors, sem_labels, sem_probs, has_semantics,
                       rgb, rgb_count, map_labels, map_probs, code, update, finish, params) -> None:
    _attribute_chunk(rows, point_index, 0, rows.shape[0], colors, has_colors, sem_labels, sem_probs,
                     has_semantics, rgb, rgb_count, map_labels, map_probs, code, update, finish, params)


def update_attributes(rows: np.ndarray, point_index: np.ndarray, colors: np.ndarray, has_colors: bool,
                      sem_labels: np.ndarray, sem_probs: np.ndarray, has_semantics: bool,
                      rgb: np.ndarray, rgb_count: np.ndarray, map_labels: np.ndarray, map_probs: np.ndarray,
                      code: int, update, finish, params: np.ndarray, n_threads: int) -> None:
    """Colour running means and label fusion (the fusion dispatcher with the rule's ``code``, kernels and
    ``params``) of attribute rows ``rows`` (-1 = skip; each row at most once) from the points ``point_index``."""
    args = (rows, point_index, colors, has_colors, sem_labels, sem_probs, has_semantics, rgb, rgb_count,
            map_labels, map_probs, code, update, finish, params)
    if n_threads > 1 and rows.shape[0] >= ROWS_PARALLEL_MIN:
        _attributes_parallel(*args, n_threads)
    else:
        _attributes_serial(*args)


@nb.njit(cache=True, nogil=True)
def decay_unseen(keys: np.ndarray, logodds: np.ndarray, seen: np.ndarray, factor: np.float32) -> int:
    """Multiply the log-odds of every stored cell whose slot is not in ``seen`` (-1 entries ignored) by
    ``factor`` (towards 0, unknown); returns the number of cells decayed."""
    mark = np.zeros(keys.shape[0], np.bool_)
    for i in range(seen.shape[0]):
        if seen[i] >= 0:
            mark[seen[i]] = True
    n = 0
    for s in range(keys.shape[0]):
        if keys[s] != -1 and not mark[s]:
            logodds[s] = logodds[s] * factor
            n += 1
    return n


@nb.njit(cache=True, nogil=True)
def max_class_id(labels: np.ndarray, empty: int) -> int:
    """Largest class id in a (N, k) uint16 array, empty slots aside (-1 when there is none)."""
    flat = labels.reshape(-1)
    best = -1
    for i in range(flat.shape[0]):
        v = np.int64(flat[i])
        if v != empty and v > best:
            best = v
    return best


def compile_parallel_variants(code: int, update, finish, params: np.ndarray) -> None:
    """Compile (or load) the many-item variants of the ray and attribute passes on a tiny input, which the
    small warm-up scans of ``compile_kernels`` would not reach."""
    grid = np.zeros(64, np.uint8)
    origin = np.zeros(3, np.float32)
    targets = np.full((2, 3), 0.05, np.float32)
    _cast_rays_parallel(origin, targets, 0.1, 10.0, grid, 32767, 32767, 32767, 4, 8, 2)
    keys = np.full(64 * 8, -1, np.int64)
    _update_parallel(np.zeros(1, np.int64), 1, np.zeros(2, np.int64), keys, np.zeros(keys.shape[0], np.float32),
                     np.full(keys.shape[0], -1, np.int32), np.zeros(64, np.int64), 8, np.float32(0.1),
                     np.float32(-2.0), np.float32(3.5), 7, np.zeros(0, np.int64))
    rows = np.zeros(1, np.int64)
    labels = np.zeros((1, 3), np.uint16)
    probs = np.zeros((1, 3), np.float32)
    _attributes_parallel(rows, rows, np.zeros((1, 3), np.uint8), True, labels, probs, True,
                         np.zeros((1, 3), np.uint8), np.zeros(1, np.uint16), labels.copy(), probs.copy(), code, update,
                         finish, params, 2)
