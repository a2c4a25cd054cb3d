"""Explicit octree (inner nodes and pruning) derived from the finest-level cells, in depth-first order.

Inner nodes follow OctoMap: occupancy = max of the children's log-odds, colour = integer mean of the
children whose colour is set (white = unset).  A parent is pruned into a leaf only when all 8 children
exist, are leaves and agree in occupancy (log-odds), written colour, top class and top confidence.
Nodes come out in OctoMap's serialisation order (pre-order, children 0..7), ready for the .ot/.bt writers.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba as nb
import numpy as np

from semmap.keys import TREE_DEPTH
from semmap.types import EMPTY_LABEL

UNSET_COLOR = 255  # OctoMap's ColorOcTree: (255, 255, 255) means "no colour"


@dataclass(frozen=True)
class OctreeNodes:
    """Every node of the pruned tree in pre-order: Morton prefix at its depth, depth, log-odds, colour,
    child mask (bit i = child i exists; 0 for leaves)."""

    codes: np.ndarray  # (N,) int64 Morton prefix at the node's depth
    depths: np.ndarray  # (N,) uint8, 0 = root
    values: np.ndarray  # (N,) float32 log-odds
    colors: np.ndarray  # (N, 3) uint8
    child_masks: np.ndarray  # (N,) uint8

    def __len__(self) -> int:
        return int(self.codes.shape[0])

    @property
    def is_leaf(self) -> np.ndarray:
        return self.child_masks == 0


@nb.njit(cache=True)
def morton_encode(kx: np.ndarray, ky: np.ndarray, kz: np.ndarray) -> np.ndarray:
    """Interleave 16-bit keys: bit 3b = x_b, 3b+1 = y_b, 3b+2 = z_b (child index = xb + 2yb + 4zb)."""
    n = kx.shape[0]
    out = np.empty(n, np.int64)
    for i in range(n):
        c = np.int64(0)
        for b in range(TREE_DEPTH):
            c |= ((np.int64(kx[i]) >> b) & 1) << (3 * b)
            c |= ((np.int64(ky[i]) >> b) & 1) << (3 * b + 1)
            c |= ((np.int64(kz[i]) >> b) & 1) << (3 * b + 2)
        out[i] = c
    return out


@nb.njit(cache=True)
def morton_decode(codes: np.ndarray) -> np.ndarray:
    """(N, 3) keys of full-depth Morton codes."""
    n = codes.shape[0]
    out = np.zeros((n, 3), np.int64)
    for i in range(n):
        c = codes[i]
        for b in range(TREE_DEPTH):
            out[i, 0] |= ((c >> (3 * b)) & 1) << b
            out[i, 1] |= ((c >> (3 * b + 1)) & 1) << b
            out[i, 2] |= ((c >> (3 * b + 2)) & 1) << b
    return out


@nb.njit(cache=True)
def _merge_level(codes, values, colors, labels, confs, leaf):
    """One level up: group children by parent, merge, prune.  Returns parent arrays and the per-child
    ``kept`` flag (False where the parent was pruned into a leaf)."""
    n = codes.shape[0]
    n_par = 0
    for i in range(n):
        if i == 0 or (codes[i] >> 3) != (codes[i - 1] >> 3):
            n_par += 1
    p_codes = np.empty(n_par, np.int64)
    p_values = np.empty(n_par, np.float32)
    p_colors = np.empty((n_par, 3), np.uint8)
    p_labels = np.full(n_par, EMPTY_LABEL, np.uint16)
    p_confs = np.zeros(n_par, np.float32)
    p_leaf = np.zeros(n_par, np.bool_)
    p_mask = np.zeros(n_par, np.uint8)
    kept = np.ones(n, np.bool_)
    start = 0
    g = 0
    while start < n:
        end = start + 1
        while end < n and (codes[end] >> 3) == (codes[start] >> 3):
            end += 1
        p_codes[g] = codes[start] >> 3
        vmax = values[start]
        sr = 0
        sg = 0
        sb = 0
        cnt = 0
        mask = 0
        same = (end - start) == 8
        for i in range(start, end):
            mask |= 1 << (codes[i] & 7)
            if values[i] > vmax:
                vmax = values[i]
            if not (colors[i, 0] == UNSET_COLOR and colors[i, 1] == UNSET_COLOR and colors[i, 2] == UNSET_COLOR):
                sr += colors[i, 0]
                sg += colors[i, 1]
                sb += colors[i, 2]
                cnt += 1
            if same and (not leaf[i] or values[i] != values[start] or labels[i] != labels[start]
                         or confs[i] != confs[start] or colors[i, 0] != colors[start, 0]
                         or colors[i, 1] != colors[start, 1] or colors[i, 2] != colors[start, 2]):
                same = False
        if same:  # prune: the parent becomes a leaf identical to its children
            p_values[g] = values[start]
            p_colors[g] = colors[start]
            p_labels[g] = labels[start]
            p_confs[g] = confs[start]
            p_leaf[g] = True
            for i in range(start, end):
                kept[i] = False
        else:
            p_values[g] = vmax
            p_mask[g] = mask
            if cnt > 0:
                p_colors[g, 0] = sr // cnt
                p_colors[g, 1] = sg // cnt
                p_colors[g, 2] = sb // cnt
            else:
                p_colors[g, 0] = UNSET_COLOR
                p_colors[g, 1] = UNSET_COLOR
                p_colors[g, 2] = UNSET_COLOR
        g += 1
        start = end
    return p_codes, p_values, p_colors, p_labels, p_confs, p_leaf, p_mask, kept


def build_tree(keys: np.ndarray, values: np.ndarray, colors: np.ndarray, labels: np.ndarray,
               confidences: np.ndarray) -> OctreeNodes:
    """Pruned octree of finest-level cells: keys (N, 3), log-odds (N,), written colours (N, 3) uint8 (white for
    free cells), top class (N,) uint16 and top confidence (N,) float32 (used only to decide pruning)."""
    if keys.shape[0] == 0:
        z = np.zeros(0, np.int64)
        return OctreeNodes(z, z.astype(np.uint8), z.astype(np.float32), np.zeros((0, 3), np.uint8), z.astype(np.uint8))
    keys = np.asarray(keys, np.int64)
    codes = morton_encode(keys[:, 0], keys[:, 1], keys[:, 2])
    order = np.argsort(codes, kind="stable")
    lvl_codes = codes[order]
    lvl_values = np.ascontiguousarray(values[order], np.float32)
    lvl_colors = np.ascontiguousarray(colors[order], np.uint8)
    lvl_labels = np.ascontiguousarray(labels[order], np.uint16)
    lvl_confs = np.ascontiguousarray(confidences[order], np.float32)
    lvl_leaf = np.ones(lvl_codes.shape[0], np.bool_)
    lvl_mask = np.zeros(lvl_codes.shape[0], np.uint8)
    parts = []
    for depth in range(TREE_DEPTH, 0, -1):
        p = _merge_level(lvl_codes, lvl_values, lvl_colors, lvl_labels, lvl_confs, lvl_leaf)
        p_codes, p_values, p_colors, p_labels, p_confs, p_leaf, p_mask, kept = p
        parts.append((depth, lvl_codes[kept], lvl_values[kept], lvl_colors[kept], lvl_mask[kept]))
        lvl_codes, lvl_values, lvl_colors, lvl_labels, lvl_confs, lvl_leaf, lvl_mask = (
            p_codes, p_values, p_colors, p_labels, p_confs, p_leaf, p_mask)
    parts.append((0, lvl_codes, lvl_values, lvl_colors, lvl_mask))
    all_codes = np.concatenate([c for _, c, _, _, _ in parts])
    depths = np.concatenate([np.full(c.shape[0], d, np.uint8) for d, c, _, _, _ in parts])
    full = all_codes << (3 * (TREE_DEPTH - depths.astype(np.int64)))
    order = np.lexsort((depths, full))
    return OctreeNodes(all_codes[order], depths[order],
                       np.concatenate([v for _, _, v, _, _ in parts])[order],
                       np.concatenate([c for _, _, _, c, _ in parts])[order],
                       np.concatenate([m for _, _, _, _, m in parts])[order])
