"""Per-frame kernels of the hashed semantic grids (voxel grid, point map): numba over flat arrays.

A frame is fused in four passes, every point counting (not only the first of each voxel):

1. ``point_keys``: OctoMap keys of the points, packed (-1 for points outside the key range) (parallel);
2. ``bucket_by_shard``: points grouped by the hash shard of their voxel (stable counting sort);
3. ``find_slots``: each point's slot in the sharded table (the octree's ``_hashtable``), inserting new voxels;
   per shard in parallel and resumable when a shard must grow, like the octree's ``update_hits``;
4. ``fuse_points``: per shard in parallel, the shard's points sorted by voxel; each voxel takes its points'
   colours (running mean), one hit, and their class evidence through the configured fusion rule (``fusion/``),
   and, for the point map, their mean position and normal.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from semmap.fusion.dense import (
    bayes_add,
    dense_top,
    normalise_logodds,
    normalise_votes,
    subtract_prior,
    vote_add,
)
from semmap.fusion.half import float_to_half, half_to_float
from semmap.fusion.max_rule import max_update
from semmap.fusion.rules import BAYES_CODE, BAYES_PRIOR_CODE, MAX_CODE, TOPK_CODE, VOTE_CODE
from semmap.fusion.topk_bayes import fuse_sets
from semmap.maps._hashtable import N_SHARDS, find_or_insert, find_slot, shard_of
from semmap.maps._keys import KEY_LIMIT, coord_to_key, pack_key

_COUNT_MAX = 65535


@nb.njit(cache=True, parallel=True)
def point_keys(points: np.ndarray, res_factor: float, out: np.ndarray) -> None:
    """Packed OctoMap keys (N,) of points taken as float32; -1 for non-finite points or keys out of range."""
    for i in nb.prange(points.shape[0]):
        x = np.float32(points[i, 0])
        y = np.float32(points[i, 1])
        z = np.float32(points[i, 2])
        if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
            out[i] = -1
            continue
        kx = coord_to_key(x, res_factor)
        ky = coord_to_key(y, res_factor)
        kz = coord_to_key(z, res_factor)
        if 0 <= kx < KEY_LIMIT and 0 <= ky < KEY_LIMIT and 0 <= kz < KEY_LIMIT:
            out[i] = pack_key(kx, ky, kz)
        else:
            out[i] = -1


@nb.njit(cache=True)
def bucket_by_shard(packed: np.ndarray):
    """Indices of the valid points grouped by shard (input order within a shard) and offsets (N_SHARDS + 1,)."""
    n = packed.shape[0]
    shard = np.empty(n, np.int64)
    offsets = np.zeros(N_SHARDS + 1, np.int64)
    for i in range(n):
        if packed[i] < 0:
            shard[i] = -1
            continue
        s = shard_of(packed[i])
        shard[i] = s
        offsets[s + 1] += 1
    for s in range(N_SHARDS):
        offsets[s + 1] += offsets[s]
    pos = offsets[:N_SHARDS].copy()
    order = np.empty(offsets[N_SHARDS], np.int64)
    for i in range(n):
        s = shard[i]
        if s >= 0:
            order[pos[s]] = i
            pos[s] += 1
    return order, offsets


@nb.njit(cache=True, parallel=True)
def find_slots(keys: np.ndarray, logodds: np.ndarray, attr: np.ndarray, counts: np.ndarray, shard_cap: int,
               packed: np.ndarray, order: np.ndarray, progress: np.ndarray, offsets: np.ndarray, fill_limit: int,
               slots: np.ndarray) -> None:
    """Slot of every bucketed point's voxel (inserted when new); a shard stops before a new key would take it
    past ``fill_limit`` or when its lane is full, and resumes at ``progress[s]`` after the table grew."""
    for sh in nb.prange(N_SHARDS):
        j = progress[sh]
        end = offsets[sh + 1]
        while j < end:
            i = order[j]
            if counts[sh] >= fill_limit and find_slot(keys, shard_cap, packed[i]) < 0:
                break
            s = find_or_insert(keys, logodds, attr, counts, sh, shard_cap, packed[i])
            if s < 0:
                break
            slots[i] = s
            j += 1
        progress[sh] = j


@nb.njit(cache=True)
def mark_new(attr: np.ndarray, slots: np.ndarray, order: np.ndarray) -> int:
    """Mark the voxels without an attribute row (-1 -> -2) and count them."""
    n = 0
    for j in range(order.shape[0]):
        s = slots[order[j]]
        if attr[s] == -1:
            attr[s] = -2
            n += 1
    return n


@nb.njit(cache=True)
def assign_rows(attr: np.ndarray, slots: np.ndarray, order: np.ndarray, n_rows: int) -> int:
    """Give every marked new voxel the next row, in bucketed point order; returns the row count."""
    for j in range(order.shape[0]):
        s = slots[order[j]]
        if attr[s] == -2:
            attr[s] = n_rows
            n_rows += 1
    return n_rows


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


@nb.njit(cache=True, parallel=True)
def fuse_points(attr: np.ndarray, logodds: np.ndarray, slots: np.ndarray, order: np.ndarray, offsets: np.ndarray,
                points: np.ndarray, colors: np.ndarray, has_colors: bool,
                sem_labels: np.ndarray, sem_probs: np.ndarray, has_semantics: bool,
                normals: np.ndarray, has_normals: bool,
                rgb: np.ndarray, rgb_count: np.ndarray, hits: np.ndarray,
                dense_f32: np.ndarray, dense_u16: np.ndarray, set_labels: np.ndarray,
                set_f32: np.ndarray, set_u16: np.ndarray, half: bool,
                positions: np.ndarray, normal_sums: np.ndarray, keep_geometry: bool,
                rule: int, prior_log: np.ndarray, clamp: float, vote_cap: float, lam: float,
                max_confidence: float, hit_log: np.float32, clamp_max: np.float32) -> None:
    """Fuse every bucketed point into its voxel (see the module docstring); each voxel is touched by one thread.

    The per-voxel state is ``dense_*`` (rows, K) for bayes / bayes-prior / vote, or ``set_labels`` +
    ``set_*`` (rows, S) for topk / max; ``half`` selects the float16-bits arrays over the float32 ones (the other
    may be empty).  Log-odds and votes are normalised once per voxel per frame, after all its points.
    """
    K = dense_f32.shape[1] if not half else dense_u16.shape[1]
    S = set_labels.shape[1]
    dense = rule in (BAYES_CODE, BAYES_PRIOR_CODE, VOTE_CODE)
    for sh in nb.prange(N_SHARDS):
        lo, hi = offsets[sh], offsets[sh + 1]
        if hi <= lo:
            continue
        pts = order[lo:hi]
        rows = np.empty(hi - lo, np.int64)
        for j in range(hi - lo):
            rows[j] = attr[slots[pts[j]]]
        by_row = np.argsort(rows, kind="mergesort")  # stable: a voxel's points stay in input order
        scratch = np.empty(max(K, 1), np.float32)
        set_l = np.empty(max(S, 1), np.uint16)
        set_p = np.empty(max(S, 1), np.float32)
        si = np.empty((3, 16), np.int64)
        sf = np.empty((3, 16), np.float64)
        j = 0
        while j < hi - lo:
            a = rows[by_row[j]]
            e = j
            while e < hi - lo and rows[by_row[e]] == a:
                e += 1
            m = e - j
            s0 = slots[pts[by_row[j]]]
            # occupancy and hits: one hit per voxel per frame (OctoMap's discretised insertion)
            v = logodds[s0] + hit_log
            logodds[s0] = clamp_max if v > clamp_max else v
            if hits[a] < _COUNT_MAX:
                hits[a] += 1
            if has_colors:  # running mean over every point's colour (a moving average once the count saturates)
                n_old = np.int64(rgb_count[a])
                n_new = min(n_old + m, _COUNT_MAX)
                w_new = np.float64(m) / (n_old + m) if n_old + m <= _COUNT_MAX else np.float64(m) / _COUNT_MAX
                for ch in range(3):
                    s = 0.0
                    for t in range(j, e):
                        s += np.float64(colors[pts[by_row[t]], ch])
                    old = np.float64(rgb[a, ch])
                    rgb[a, ch] = np.uint8(np.int64(old + (s / m - old) * w_new + 0.5))
                rgb_count[a] = n_new
            if keep_geometry:  # point map: mean position (exact running mean) and summed normals
                n_prev = np.float64(hits[a] - 1) if hits[a] < _COUNT_MAX else np.float64(_COUNT_MAX - 1)
                for ax in range(3):
                    s = 0.0
                    for t in range(j, e):
                        s += np.float64(points[pts[by_row[t]], ax])
                    positions[a, ax] = np.float32((positions[a, ax] * n_prev + s / m) / (n_prev + 1.0))
                    if has_normals:
                        sn = 0.0
                        for t in range(j, e):
                            sn += np.float64(normals[pts[by_row[t]], ax])
                        normal_sums[a, ax] += np.float32(sn)
            if has_semantics:
                if dense:
                    _load(dense_f32, dense_u16, half, a, scratch)
                    if rule == VOTE_CODE:
                        voted = False
                        for t in range(j, e):
                            voted |= vote_add(scratch, sem_labels[pts[by_row[t]]])
                        if voted:
                            normalise_votes(scratch, vote_cap)
                    else:
                        n_sem = 0
                        for t in range(j, e):
                            p = pts[by_row[t]]
                            if bayes_add(scratch, sem_labels[p], sem_probs[p]):
                                n_sem += 1
                        if n_sem > 0:
                            if rule == BAYES_PRIOR_CODE:
                                subtract_prior(scratch, prior_log, np.float64(n_sem))
                            normalise_logodds(scratch, clamp)
                    _store(dense_f32, dense_u16, half, a, scratch)
                else:
                    for c in range(S):
                        set_l[c] = set_labels[a, c]
                        set_p[c] = half_to_float(set_u16[a, c]) if half else set_f32[a, c]
                    for t in range(j, e):
                        p = pts[by_row[t]]
                        if rule == TOPK_CODE:
                            fuse_sets(set_l, set_p, sem_labels[p], sem_probs[p], lam, max_confidence,
                                      set_l, set_p, si, sf)
                        elif rule == MAX_CODE:
                            lab, conf = max_update(set_l[0], set_p[0], sem_labels[p, 0], sem_probs[p, 0],
                                                   max_confidence)
                            set_l[0] = lab
                            set_p[0] = conf
                    for c in range(S):
                        set_labels[a, c] = set_l[c]
                        if half:
                            set_u16[a, c] = float_to_half(set_p[c])
                        else:
                            set_f32[a, c] = set_p[c]
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
