"""Merge finest-level cells into their parents (numba): the inner-node rules of the semantic OctoMap paper."""

from __future__ import annotations

import numba as nb
import numpy as np

from semmap.fusion.dispatch import merge_voxel, new_scratch
from semmap.types import EMPTY_LABEL


@nb.njit(cache=True)
def coarsen_cells(parent: np.ndarray, logodds: np.ndarray, attr: np.ndarray, rgb: np.ndarray,
                  rgb_count: np.ndarray, sem_labels: np.ndarray, sem_probs: np.ndarray,
                  code: int, layout: int, update, params: np.ndarray):
    """Group cells by ``parent`` key (sorted ascending) and merge each group: max log-odds, colour = mean of
    the children's means weighted by their observation counts, class states merged in key order by the fusion
    dispatcher (``topk``: the children's sets fused by Algorithm 1).  Returns the parent cells compacted."""
    n = parent.shape[0]
    s = sem_labels.shape[1]
    w = sem_probs.shape[1]
    n_groups = 0
    for i in range(n):
        if i == 0 or parent[i] != parent[i - 1]:
            n_groups += 1
    out_key = np.empty(n_groups, np.int64)
    out_lo = np.empty(n_groups, np.float32)
    out_attr = np.full(n_groups, -1, np.int32)
    o_sum = np.zeros((n_groups, 3), np.float64)
    o_cnt = np.zeros(n_groups, np.int64)
    o_lab = np.full((n_groups, s), EMPTY_LABEL, np.uint16)
    o_prob = np.zeros((n_groups, w), np.float32)
    si, sf = new_scratch()
    g = -1
    n_attr = 0
    for i in range(n):
        if i == 0 or parent[i] != parent[i - 1]:
            g += 1
            out_key[g] = parent[i]
            out_lo[g] = logodds[i]
        elif logodds[i] > out_lo[g]:
            out_lo[g] = logodds[i]
        a = attr[i]
        if a < 0:
            continue
        if out_attr[g] < 0:
            out_attr[g] = n_attr
            n_attr += 1
        r = out_attr[g]
        for c in range(3):
            o_sum[r, c] += np.float64(rgb[a, c]) * rgb_count[a]
        o_cnt[r] += rgb_count[a]
        merge_voxel(code, layout, update, o_lab[r], o_prob[r], sem_labels[a], sem_probs[a], params, si, sf)
    o_rgb = np.zeros((n_attr, 3), np.uint8)
    o_n = np.zeros(n_attr, np.uint16)
    for r in range(n_attr):
        if o_cnt[r] > 0:
            for c in range(3):
                o_rgb[r, c] = np.uint8(np.int64(o_sum[r, c] / o_cnt[r] + 0.5))
            o_n[r] = min(o_cnt[r], 65535)
    return out_key, out_lo, out_attr, o_rgb, o_n, o_lab[:n_attr], o_prob[:n_attr]
