"""Per-frame kernels of the hashed semantic grids (voxel grid, point map): numba over flat arrays.

A frame is fused in five passes, every point counting (not only the first of each voxel):

1. ``point_keys``: OctoMap keys of the points, packed (-1 for points outside the key range) (parallel);
2. ``bucket_by_shard``: points grouped by the hash shard of their voxel (stable counting sort);
3. ``group_shards``: within each shard, points grouped by key with a local hash table, so a voxel's points are
   one run (parallel, O(n));
4. ``find_voxels``: one table lookup per voxel of the frame (not per point) in the sharded table (the octree's
   ``_hashtable``), inserting new voxels and counting them per shard (parallel over shards);
5. ``fuse_points``: per shard in parallel, new voxels get their attribute rows and each voxel takes its points'
   colours (running mean), one hit, and their class evidence through the configured fusion rule (``fusion/``),
   and, for the point map, their mean position and normal.

A frame with nothing but colour into a grid without geometry (the run's dense cloud, ``cloud.ply``) takes a
shorter way: ``merge_voxels`` replaces pass 3 and merges each voxel's points (count, summed colour), so
``find_voxels`` and ``fuse_voxels`` run once per voxel, without reading the points again.  The sums are exact
integers, so the voxels, rows and colour means are those of the per-point passes.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from semmap.fusion.dense import dense_top
from semmap.fusion.dispatch import GENERIC, LAYOUT_SET, finish_voxel, fuse_measurement, new_scratch
from semmap.fusion.half import float_to_half, half_to_float
from semmap.maps._hashtable import N_SHARDS, find_or_insert, key_hash, shard_of
from semmap.maps._keys import KEY_LIMIT, coord_to_key, pack_key

_COUNT_MAX = 65535


@nb.njit(cache=True, parallel=True)
def point_keys(points: np.ndarray, res_factor: float, out: np.ndarray, shard: np.ndarray) -> None:
    """Packed OctoMap keys (N,) of points taken as float32 and their hash shards; key -1 (shard -1) for non-finite
    points or keys out of range."""
    for i in nb.prange(points.shape[0]):
        x = np.float32(points[i, 0])
        y = np.float32(points[i, 1])
        z = np.float32(points[i, 2])
        if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
            out[i] = -1
            shard[i] = -1
            continue
        kx = coord_to_key(x, res_factor)
        ky = coord_to_key(y, res_factor)
        kz = coord_to_key(z, res_factor)
        if 0 <= kx < KEY_LIMIT and 0 <= ky < KEY_LIMIT and 0 <= kz < KEY_LIMIT:
            out[i] = pack_key(kx, ky, kz)
            shard[i] = shard_of(out[i])
        else:
            out[i] = -1
            shard[i] = -1


@nb.njit(cache=True)
def bucket_by_shard(packed: np.ndarray, shard: np.ndarray):
    """The valid points grouped by shard (input order within a shard): their indices, their keys, and the shard
    offsets (N_SHARDS + 1,).  Keys are copied beside the indices so later passes read them in order."""
    n = packed.shape[0]
    offsets = np.zeros(N_SHARDS + 1, np.int64)
    for i in range(n):
        if shard[i] >= 0:
            offsets[shard[i] + 1] += 1
    for s in range(N_SHARDS):
        offsets[s + 1] += offsets[s]
    pos = offsets[:N_SHARDS].copy()
    order = np.empty(offsets[N_SHARDS], np.int64)
    keys = np.empty(offsets[N_SHARDS], np.int64)
    for i in range(n):
        s = shard[i]
        if s >= 0:
            order[pos[s]] = i
            keys[pos[s]] = packed[i]
            pos[s] += 1
    return order, keys, offsets


@nb.njit(cache=True, parallel=True)
def group_shards(order: np.ndarray, keys: np.ndarray, offsets: np.ndarray, out_pts: np.ndarray,
                 out_keys: np.ndarray, voxels: np.ndarray) -> None:
    """Within each shard, its points grouped by key into ``out_pts`` / ``out_keys`` (voxels in order of first
    appearance, a voxel's points in input order) with a small local hash table: O(n), no sort; ``voxels[s]`` =
    distinct keys in shard s."""
    for sh in nb.prange(N_SHARDS):
        lo, hi = offsets[sh], offsets[sh + 1]
        n = hi - lo
        if n == 0:
            voxels[sh] = 0
            continue
        cap = 16
        while cap < 2 * n:
            cap *= 2
        table_keys = np.full(cap, np.int64(-1))
        table_ids = np.empty(cap, np.int64)
        ids = np.empty(n, np.int64)
        first = np.empty(n, np.int64)  # key of each local voxel id
        count = np.zeros(n + 1, np.int64)
        n_ids = 0
        for j in range(n):
            k = keys[lo + j]
            h = np.int64(key_hash(k) & np.uint64(cap - 1))
            while table_keys[h] != k and table_keys[h] != -1:
                h = (h + 1) & (cap - 1)
            if table_keys[h] == -1:
                table_keys[h] = k
                table_ids[h] = n_ids
                first[n_ids] = k
                n_ids += 1
            ids[j] = table_ids[h]
            count[ids[j] + 1] += 1
        for v in range(n_ids):
            count[v + 1] += count[v]
        for j in range(n):
            dst = lo + count[ids[j]]
            count[ids[j]] += 1
            out_pts[dst] = order[lo + j]
            out_keys[dst] = keys[lo + j]
        voxels[sh] = n_ids


@nb.njit(cache=True, parallel=True)
def merge_voxels(order: np.ndarray, keys: np.ndarray, offsets: np.ndarray, colors: np.ndarray, has_colors: bool,
                 vox_keys: np.ndarray, vox_points: np.ndarray, vox_rgb: np.ndarray, voxels: np.ndarray) -> None:
    """Frames with nothing but colour (the dense cloud): within each shard, its points merged per voxel with the
    local hash table of :func:`group_shards` (voxels in order of first appearance, from the shard's offset): the
    key, the number of points and the summed colour of each, so later passes run once per voxel, not per point.
    ``voxels[s]`` = distinct keys in shard s."""
    for sh in nb.prange(N_SHARDS):
        lo, hi = offsets[sh], offsets[sh + 1]
        n = hi - lo
        cap = 16
        while cap < 2 * n:
            cap *= 2
        table_keys = np.full(cap, np.int64(-1))
        table_ids = np.empty(cap, np.int64)
        n_ids = 0
        last_k, v = np.int64(-1), np.int64(-1)
        for j in range(lo, hi):
            k = keys[j]
            if k != last_k:  # (a voxel's points often follow each other: no lookup for those)
                h = np.int64(key_hash(k) & np.uint64(cap - 1))
                while table_keys[h] != k and table_keys[h] != -1:
                    h = (h + 1) & (cap - 1)
                if table_keys[h] == -1:
                    table_keys[h] = k
                    table_ids[h] = lo + n_ids
                    vox_keys[lo + n_ids] = k
                    vox_points[lo + n_ids] = 0
                    vox_rgb[lo + n_ids, 0] = 0
                    vox_rgb[lo + n_ids, 1] = 0
                    vox_rgb[lo + n_ids, 2] = 0
                    n_ids += 1
                last_k, v = k, table_ids[h]
            vox_points[v] += 1
            if has_colors:
                p = order[j]
                vox_rgb[v, 0] += np.int64(colors[p, 0])
                vox_rgb[v, 1] += np.int64(colors[p, 1])
                vox_rgb[v, 2] += np.int64(colors[p, 2])
        voxels[sh] = n_ids


@nb.njit(cache=True, inline="always")
def _hit_voxel(attr, logodds, hits, s0, next_row, hit_log, clamp_max):
    """A frame's hit on the voxel in table slot ``s0``: its attribute row (the shard's next free row if the voxel
    is new), the hit log-odds added under the clamp, one more hit; returns (row, next free row)."""
    if attr[s0] == -2:
        attr[s0] = next_row
        next_row += 1
    a = attr[s0]
    v = logodds[s0] + hit_log
    logodds[s0] = clamp_max if v > clamp_max else v
    if hits[a] < _COUNT_MAX:
        hits[a] += 1
    return a, next_row


@nb.njit(cache=True, parallel=True)
def fuse_voxels(attr: np.ndarray, logodds: np.ndarray, offsets: np.ndarray, voxels: np.ndarray,
                vox_slot: np.ndarray, first_row: np.ndarray, vox_points: np.ndarray, vox_rgb: np.ndarray,
                has_colors: bool, rgb: np.ndarray, rgb_count: np.ndarray, hits: np.ndarray,
                hit_log: np.float32, clamp_max: np.float32) -> None:
    """:func:`fuse_points` for the merged voxels of :func:`merge_voxels` (no classes, no geometry): the same
    rows, hit, occupancy and colour mean, from each voxel's point count and summed colour (exact integers, so the
    same numbers as summing its points one by one)."""
    for sh in nb.prange(N_SHARDS):
        next_row = first_row[sh]
        for j in range(offsets[sh], offsets[sh] + voxels[sh]):
            a, next_row = _hit_voxel(attr, logodds, hits, vox_slot[j], next_row, hit_log, clamp_max)
            if has_colors:
                _add_colours(rgb, rgb_count, a, vox_points[j], np.float64(vox_rgb[j, 0]), np.float64(vox_rgb[j, 1]),
                             np.float64(vox_rgb[j, 2]))


@nb.njit(cache=True, parallel=True)
def find_voxels(keys: np.ndarray, logodds: np.ndarray, attr: np.ndarray, counts: np.ndarray, shard_cap: int,
                sorted_keys: np.ndarray, offsets: np.ndarray, ends: np.ndarray, run_slot: np.ndarray,
                new_rows: np.ndarray, failed: np.ndarray) -> None:
    """Slot of each voxel of the frame (stored at its first point's position in ``run_slot``), inserted when new;
    shard s's keys are ``sorted_keys[offsets[s]:ends[s]]``.  New voxels are marked (attribute row -2) and counted
    per shard.  ``failed[s]``: a lane of shard s was full (grow the table and call again; keys found so far stay)."""
    for sh in nb.prange(N_SHARDS):
        failed[sh] = False
        n_new = 0
        prev = np.int64(-1)
        for j in range(offsets[sh], ends[sh]):
            k = sorted_keys[j]
            if k == prev:
                continue
            prev = k
            s = find_or_insert(keys, logodds, attr, counts, sh, shard_cap, k)
            if s < 0:
                failed[sh] = True
                break
            run_slot[j] = s
            if attr[s] == -1:
                attr[s] = -2
            if attr[s] == -2:
                n_new += 1
        new_rows[sh] = n_new


@nb.njit(cache=True, inline="always")
def _load(state_f32, state_u16, half: bool, a: int, out: np.ndarray) -> None:
    if half:
        for c in range(out.shape[0]):
            out[c] = half_to_float(state_u16[a, c])
    else:
        for c in range(out.shape[0]):
            out[c] = state_f32[a, c]


@nb.njit(cache=True, inline="always")
def _store(state_f32, state_u16, half: bool, a: int, src: np.ndarray) -> None:
    if half:
        for c in range(src.shape[0]):
            state_u16[a, c] = float_to_half(src[c])
    else:
        for c in range(src.shape[0]):
            state_f32[a, c] = src[c]


@nb.njit(cache=True, inline="always")
def _blend(rgb: np.ndarray, a: int, ch: int, mean: float, w: float) -> None:
    old = np.float64(rgb[a, ch])
    rgb[a, ch] = np.uint8(np.int64(old + (mean - old) * w + 0.5))


@nb.njit(cache=True, inline="always")
def _add_colours(rgb, rgb_count, a, m, sum_r, sum_g, sum_b) -> None:
    """Row ``a``'s colour takes ``m`` more points whose colours sum to (``sum_r``, ``sum_g``, ``sum_b``): a running
    mean over every point's colour, a moving average once the count saturates."""
    n_old = np.int64(rgb_count[a])
    w = np.float64(m) / (n_old + m) if n_old + m <= _COUNT_MAX else np.float64(m) / _COUNT_MAX
    _blend(rgb, a, 0, sum_r / m, w)
    _blend(rgb, a, 1, sum_g / m, w)
    _blend(rgb, a, 2, sum_b / m, w)
    rgb_count[a] = min(n_old + m, _COUNT_MAX)


@nb.njit(cache=True, parallel=True)
def fuse_points(attr: np.ndarray, logodds: np.ndarray, sorted_pts: np.ndarray, offsets: np.ndarray,
                run_slot: np.ndarray, sorted_keys: np.ndarray, first_row: np.ndarray,
                points: np.ndarray, colors: np.ndarray, has_colors: bool,
                sem_labels: np.ndarray, sem_probs: np.ndarray, has_semantics: bool,
                normals: np.ndarray, has_normals: bool,
                rgb: np.ndarray, rgb_count: np.ndarray, hits: np.ndarray,
                dense_f32: np.ndarray, dense_u16: np.ndarray, set_labels: np.ndarray,
                set_f32: np.ndarray, set_u16: np.ndarray, half: bool,
                positions: np.ndarray, normal_sums: np.ndarray, keep_geometry: bool,
                code: int, layout: int, update, finish, params: np.ndarray,
                hit_log: np.float32, clamp_max: np.float32) -> None:
    """Fuse every point into its voxel (see the module docstring); a shard's voxels are one thread's.

    New voxels (row -2) get rows ``first_row[s], first_row[s] + 1, ...`` in key order.  The per-voxel state is
    ``dense_*`` (rows, K) for the dense layouts, or ``set_labels`` + ``set_*`` (rows, S) for a set rule;
    ``half`` selects the float16-bits arrays over the float32 ones (the other may be empty).  Each point's class
    set goes through the fusion dispatcher (``code``, ``update``, ``finish``, ``params``: the rule's entry and
    settings), which normalises once per voxel per frame, after all its points.
    """
    K = dense_f32.shape[1] if not half else dense_u16.shape[1]
    S = set_labels.shape[1]
    dense = layout != LAYOUT_SET
    W = K if dense else S
    inputs = (points, colors, sem_labels, sem_probs, normals)  # grouped: a numba call takes at most 30 arguments
    flags = (has_colors, has_semantics, has_normals, half, keep_geometry)
    state = (dense_f32, dense_u16, set_labels, set_f32, set_u16)
    for sh in nb.prange(N_SHARDS):
        if code == GENERIC:  # the rule's test hoisted out of the loops (see fusion.dispatch.fuse_measurement)
            _fuse_shard(sh, True, attr, logodds, sorted_pts, offsets, run_slot, sorted_keys, first_row, inputs, flags,
                        rgb, rgb_count, hits, state, positions, normal_sums, code, update, finish, params, hit_log,
                        clamp_max, S, W, dense)
        else:
            _fuse_shard(sh, False, attr, logodds, sorted_pts, offsets, run_slot, sorted_keys, first_row, inputs,
                        flags, rgb, rgb_count, hits, state, positions, normal_sums, code, update, finish, params,
                        hit_log, clamp_max, S, W, dense)


@nb.njit(cache=True, inline="always")
def _fuse_shard(sh: int, generic: bool, attr, logodds, sorted_pts, offsets, run_slot, sorted_keys, first_row, inputs,
                flags, rgb, rgb_count, hits, state, positions, normal_sums, code, update, finish, params, hit_log,
                clamp_max, S, W, dense) -> None:
    """One shard of :func:`fuse_points` (``generic``: the rule has no fast path in the dispatcher)."""
    points, colors, sem_labels, sem_probs, normals = inputs
    has_colors, has_semantics, has_normals, half, keep_geometry = flags
    dense_f32, dense_u16, set_labels, set_f32, set_u16 = state
    lo, hi = offsets[sh], offsets[sh + 1]
    if hi <= lo:
        return
    next_row = first_row[sh]
    w_lab = np.empty(S, np.uint16)  # the voxel's state in working form
    w_val = np.empty(W, np.float32)
    si, sf = new_scratch()
    j = lo
    while j < hi:
        key = sorted_keys[j]
        e = j + 1
        while e < hi and sorted_keys[e] == key:
            e += 1
        m = e - j
        # its row (a new one for a new voxel), occupancy and hits: one hit per voxel per frame (OctoMap's
        # discretised insertion)
        a, next_row = _hit_voxel(attr, logodds, hits, run_slot[j], next_row, hit_log, clamp_max)
        if dense and has_semantics:
            _load(dense_f32, dense_u16, half, a, w_val)
        elif has_semantics:
            for c in range(S):
                w_lab[c] = set_labels[a, c]
                w_val[c] = half_to_float(set_u16[a, c]) if half else set_f32[a, c]
        cr = cg = cb = 0.0
        px = py = pz = 0.0
        nx = ny = nz = 0.0
        n_sem = 0
        for t in range(j, e):  # one pass over the voxel's points
            p = sorted_pts[t]
            if has_colors:
                cr += np.float64(colors[p, 0])
                cg += np.float64(colors[p, 1])
                cb += np.float64(colors[p, 2])
            if keep_geometry:
                px += np.float64(points[p, 0])
                py += np.float64(points[p, 1])
                pz += np.float64(points[p, 2])
                if has_normals:
                    nx += np.float64(normals[p, 0])
                    ny += np.float64(normals[p, 1])
                    nz += np.float64(normals[p, 2])
            if has_semantics and fuse_measurement(generic, code, update, w_lab, w_val, sem_labels[p], sem_probs[p],
                                                  params, si, sf):
                n_sem += 1
        if has_colors:
            _add_colours(rgb, rgb_count, a, m, cr, cg, cb)
        if keep_geometry:  # point map: running mean of the frames' mean points, summed normals
            n_prev = np.float64(min(hits[a], _COUNT_MAX - 1) - 1)
            positions[a, 0] = np.float32((positions[a, 0] * n_prev + px / m) / (n_prev + 1.0))
            positions[a, 1] = np.float32((positions[a, 1] * n_prev + py / m) / (n_prev + 1.0))
            positions[a, 2] = np.float32((positions[a, 2] * n_prev + pz / m) / (n_prev + 1.0))
            if has_normals:
                normal_sums[a, 0] += np.float32(nx)
                normal_sums[a, 1] += np.float32(ny)
                normal_sums[a, 2] += np.float32(nz)
        if has_semantics:
            finish_voxel(generic, code, finish, w_lab, w_val, n_sem, params)
            if dense:
                if n_sem > 0:
                    _store(dense_f32, dense_u16, half, a, w_val)
            else:
                for c in range(S):
                    set_labels[a, c] = w_lab[c]
                    if half:
                        set_u16[a, c] = float_to_half(w_val[c])
                    else:
                        set_f32[a, c] = w_val[c]
        j = e


@nb.njit(cache=True, parallel=True)
def dense_summary(dense_f32: np.ndarray, dense_u16: np.ndarray, half: bool, rows: np.ndarray, logodds: bool,
                  labels: np.ndarray, confidence: np.ndarray, entropy: np.ndarray) -> None:
    """Most probable class, its probability and the entropy (nats) of each listed row's dense state;
    rows without evidence (all zero) get no class (labels keep their EMPTY fill)."""
    K = dense_f32.shape[1] if not half else dense_u16.shape[1]
    for i in nb.prange(rows.shape[0]):
        state = np.empty(K, np.float32)
        _load(dense_f32, dense_u16, half, rows[i], state)
        any_evidence = False
        for c in range(K):
            if state[c] != 0.0:
                any_evidence = True
                break
        if not any_evidence:
            continue
        best, p, ent = dense_top(state, logodds)
        labels[i] = best
        confidence[i] = p
        entropy[i] = ent
