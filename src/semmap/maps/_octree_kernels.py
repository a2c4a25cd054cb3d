"""Per-frame insertion kernels of the semantic OctoMap (numba, flat arrays).

One scan is inserted as OctoMap's ``insertPointCloud(discretize=True)`` does it, in five passes:

1. ``point_keys``: keys of all endpoints and their bounding box (parallel, one chunk per thread);
2. ``dedupe_endpoints``: voxel filter: the first point of each endpoint cell represents it; its cell is
   marked "hit" (2) in a temporary byte grid over the scan's bounding box (serial, O(N));
3. ``cast_rays``: rays from the origin to each endpoint cell centre (or to the max-range point) mark
   untouched cells "free" (1); hits are never overwritten, so "occupied wins" needs no set difference
   and threads write only the value 1, so they need no atomics (parallel over rays);
4. ``collect_free``: free cells gathered in grid order and bucketed by hash shard; the grid is reset to
   zero on the way so the buffer can be reused (parallel over x-slabs);
5. ``update_free`` / ``update_hits``: log-odds update per shard (parallel over shards), then colour
   averaging and top-k Bayesian fusion for the hit cells (parallel over cells).
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from semmap.fusion.topk_bayes import fuse_sets
from semmap.maps._hashtable import N_SHARDS, find_or_insert, find_slot, shard_of
from semmap.maps._keys import KEY_LIMIT, coord_to_key, key_to_coord, pack_key, trace_ray


@nb.njit(cache=True, parallel=True)
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


@nb.njit(cache=True)
def dedupe_endpoints(keys: np.ndarray, valid: np.ndarray, grid: np.ndarray,
                     g0x: int, g0y: int, g0z: int, gnx: int, gny: int, gnz: int, out: np.ndarray) -> np.ndarray:
    """Index of the first point in each endpoint cell inside the grid, in input order (a view of ``out``, which
    must hold N entries); marks those cells 2."""
    m = 0
    for i in range(valid.shape[0]):
        if not valid[i]:
            continue
        x = keys[i, 0] - g0x
        y = keys[i, 1] - g0y
        z = keys[i, 2] - g0z
        if x < 0 or y < 0 or z < 0 or x >= gnx or y >= gny or z >= gnz:
            continue  # beyond the range-limited grid: a max-range reading, handled by the caller
        idx = (x * gny + y) * gnz + z
        if grid[idx] == 0:
            grid[idx] = 2
            out[m] = i
            m += 1
    return out[:m]


@nb.njit(cache=True, parallel=True)
def endpoint_targets(keys: np.ndarray, first: np.ndarray, origin: np.ndarray, resolution: float,
                     max_range: float, grid: np.ndarray, g0x: int, g0y: int, g0z: int,
                     gnx: int, gny: int, gnz: int):
    """Ray targets (M, 3) float32 of the endpoint cells and whether each is a hit (within max range).

    Targets are the cell centres (discretised insertion).  A centre farther than ``max_range`` (>= 0)
    becomes ``origin + dir * max_range`` in float32 arithmetic, as OctoMap's computeUpdate does, and its
    grid mark is cleared because a max-range reading has no occupied end.
    """
    m = first.shape[0]
    targets = np.empty((m, 3), np.float32)
    hit = np.empty(m, np.bool_)
    ox, oy, oz = origin[0], origin[1], origin[2]
    for j in nb.prange(m):
        i = first[j]
        cx = np.float32(key_to_coord(keys[i, 0], resolution))
        cy = np.float32(key_to_coord(keys[i, 1], resolution))
        cz = np.float32(key_to_coord(keys[i, 2], resolution))
        dx = cx - ox
        dy = cy - oy
        dz = cz - oz
        dist = math.sqrt(np.float64(dx * dx + dy * dy + dz * dz))
        if max_range < 0.0 or dist <= max_range:
            hit[j] = True
            targets[j, 0] = cx
            targets[j, 1] = cy
            targets[j, 2] = cz
        else:
            hit[j] = False
            inv = np.float32(dist)
            mr = np.float32(max_range)
            targets[j, 0] = ox + (dx / inv) * mr
            targets[j, 1] = oy + (dy / inv) * mr
            targets[j, 2] = oz + (dz / inv) * mr
            x, y, z = keys[i, 0] - g0x, keys[i, 1] - g0y, keys[i, 2] - g0z
            if 0 <= x < gnx and 0 <= y < gny and 0 <= z < gnz:
                grid[(x * gny + y) * gnz + z] = 0
    return targets, hit


@nb.njit(cache=True, parallel=True)
def cast_rays(origin: np.ndarray, targets: np.ndarray, resolution: float, res_factor: float,
              grid: np.ndarray, g0x: int, g0y: int, g0z: int, gny: int, gnz: int, n_chunks: int) -> int:
    """Mark the free cells of every ray origin→target in the grid; returns the number of cells visited."""
    m = targets.shape[0]
    chunk = (m + n_chunks - 1) // n_chunks
    steps = np.zeros(n_chunks, np.int64)
    dummy = np.empty((0, 3), np.int64)
    ox, oy, oz = origin[0], origin[1], origin[2]
    for c in nb.prange(n_chunks):
        s = 0
        for j in range(c * chunk, min(m, (c + 1) * chunk)):
            r = trace_ray(ox, oy, oz, targets[j, 0], targets[j, 1], targets[j, 2], resolution, res_factor,
                          grid, g0x, g0y, g0z, gny, gnz, dummy, False)
            if r > 0:
                s += r
        steps[c] = s
    return steps.sum()


@nb.njit(cache=True, parallel=True)
def collect_free(grid: np.ndarray, g0x: int, g0y: int, g0z: int, gnx: int, gny: int, gnz: int):
    """Packed keys of the free cells (grid value 1), grouped by hash shard and in grid order within a shard,
    with the shard offsets (N_SHARDS + 1,).  Resets every touched grid cell to 0.

    ``gnz`` must be a multiple of 8: the grid is scanned 8 bytes at a time, skipping untouched words.
    """
    plane = gny * gnz
    words = grid[: gnx * plane].view(np.uint64)
    wplane = plane // 8
    counts = np.zeros((gnx, N_SHARDS), np.int64)
    for x in nb.prange(gnx):
        wbase = x * wplane
        for w in range(wplane):
            if words[wbase + w] == 0:
                continue
            for b in range(8):
                r = w * 8 + b
                if grid[x * plane + r] == 1:
                    y = r // gnz
                    z = r - y * gnz
                    counts[x, shard_of(pack_key(g0x + x, g0y + y, g0z + z))] += 1
    # exclusive prefix sum in shard-major order: shard s, then slab x
    offsets = np.zeros(N_SHARDS + 1, np.int64)
    starts = np.empty((gnx, N_SHARDS), np.int64)
    total = 0
    for s in range(N_SHARDS):
        offsets[s] = total
        for x in range(gnx):
            starts[x, s] = total
            total += counts[x, s]
    offsets[N_SHARDS] = total
    out = np.empty(total, np.int64)
    for x in nb.prange(gnx):
        wbase = x * wplane
        pos = starts[x].copy()
        for w in range(wplane):
            if words[wbase + w] == 0:
                continue
            for b in range(8):
                r = w * 8 + b
                v = grid[x * plane + r]
                if v == 1:
                    y = r // gnz
                    z = r - y * gnz
                    k = pack_key(g0x + x, g0y + y, g0z + z)
                    s = shard_of(k)
                    out[pos[s]] = k
                    pos[s] += 1
            words[wbase + w] = 0
    return out, offsets


@nb.njit(cache=True)
def bucket_by_shard(packed: np.ndarray):
    """Stable order of packed keys grouped by shard, and shard offsets (N_SHARDS + 1,)."""
    n = packed.shape[0]
    shard = np.empty(n, np.int64)
    counts = np.zeros(N_SHARDS + 1, np.int64)
    for i in range(n):
        s = shard_of(packed[i])
        shard[i] = s
        counts[s + 1] += 1
    for s in range(N_SHARDS):
        counts[s + 1] += counts[s]
    pos = counts[:N_SHARDS].copy()
    order = np.empty(n, np.int64)
    for i in range(n):
        s = shard[i]
        order[pos[s]] = i
        pos[s] += 1
    return order, counts


@nb.njit(cache=True, parallel=True)
def update_free(keys: np.ndarray, logodds: np.ndarray, attr: np.ndarray, counts: np.ndarray, shard_cap: int,
                free: np.ndarray, progress: np.ndarray, offsets: np.ndarray, miss: np.float32,
                clamp_min: np.float32, fill_limit: int) -> None:
    """Add the miss log-odds to every free cell (creating it at 0 first), clamped below; per shard in parallel.

    ``progress[s]`` is where shard s resumes; a shard stops before a new key would take it past ``fill_limit``
    entries; when some shard stopped short of ``offsets[s + 1]``, grow the table and call again.
    """
    for sh in nb.prange(N_SHARDS):
        i = progress[sh]
        end = offsets[sh + 1]
        while i < end:
            if counts[sh] >= fill_limit and find_slot(keys, shard_cap, free[i]) < 0:
                break
            s = find_or_insert(keys, logodds, attr, counts, sh, shard_cap, free[i])
            if s < 0:  # lane full: grow and resume here
                break
            v = logodds[s] + miss
            logodds[s] = clamp_min if v < clamp_min else v
            i += 1
        progress[sh] = i


@nb.njit(cache=True, parallel=True)
def update_hits(keys: np.ndarray, logodds: np.ndarray, attr: np.ndarray, counts: np.ndarray, shard_cap: int,
                hit_keys: np.ndarray, order: np.ndarray, progress: np.ndarray, offsets: np.ndarray,
                hit: np.float32, clamp_max: np.float32, fill_limit: int, slots: np.ndarray) -> None:
    """Add the hit log-odds to every hit cell, clamped above, recording its slot; resumable like
    :func:`update_free`."""
    for sh in nb.prange(N_SHARDS):
        j = progress[sh]
        end = offsets[sh + 1]
        while j < end:
            i = order[j]
            if counts[sh] >= fill_limit and find_slot(keys, shard_cap, hit_keys[i]) < 0:
                break
            s = find_or_insert(keys, logodds, attr, counts, sh, shard_cap, hit_keys[i])
            if s < 0:  # lane full: grow and resume here
                break
            slots[i] = s
            v = logodds[s] + hit
            logodds[s] = clamp_max if v > clamp_max else v
            j += 1
        progress[sh] = j


@nb.njit(cache=True)
def assign_attributes(attr: np.ndarray, slots: np.ndarray, n_attr: int) -> int:
    """Give every hit slot without attributes the next free attribute row; returns the new row count."""
    for i in range(slots.shape[0]):
        s = slots[i]
        if s >= 0 and attr[s] < 0:
            attr[s] = n_attr
            n_attr += 1
    return n_attr


@nb.njit(cache=True, parallel=True)
def update_attributes(attr: np.ndarray, slots: np.ndarray, point_index: np.ndarray,
                      colors: np.ndarray, has_colors: bool,
                      sem_labels: np.ndarray, sem_probs: np.ndarray, has_semantics: bool,
                      rgb: np.ndarray, rgb_count: np.ndarray, map_labels: np.ndarray, map_probs: np.ndarray,
                      lam: float, max_confidence: float, n_chunks: int) -> None:
    """Colour running means and top-k Bayesian label fusion for the hit cells (each row touched once)."""
    m = slots.shape[0]
    chunk = (m + n_chunks - 1) // n_chunks
    for c in nb.prange(n_chunks):
        si = np.empty((3, 16), np.int64)
        sf = np.empty((3, 16), np.float64)
        for j in range(c * chunk, min(m, (c + 1) * chunk)):
            s = slots[j]
            if s < 0:
                continue
            a = attr[s]
            p = point_index[j]
            if has_colors:  # running mean (a slow moving average once the count saturates)
                n = np.int64(rgb_count[a]) + 1
                if n > 65535:
                    n = 65535
                rgb_count[a] = n
                for ch in range(3):
                    m = np.float64(rgb[a, ch])
                    rgb[a, ch] = np.uint8(np.int64(m + (np.float64(colors[p, ch]) - m) / n + 0.5))
            if has_semantics:
                fuse_sets(map_labels[a], map_probs[a], sem_labels[p], sem_probs[p], lam, max_confidence,
                          map_labels[a], map_probs[a], si, sf)
