"""Slow, obviously-correct reference versions of the kernels, for comparison on small inputs."""

from __future__ import annotations

import numpy as np

EMPTY = 65535


def fuse_reference(map_set: dict[int, float], meas_set: dict[int, float], lam: float,
                   k: int = 3, max_confidence: float = 1.0) -> dict[int, float]:
    """Algorithm 1 + Bayes + top-k, written with dicts straight from the paper's pseudocode."""
    return fuse_reference_posterior(map_set, meas_set, lam, k, max_confidence)[0]


def fuse_reference_posterior(map_set: dict[int, float], meas_set: dict[int, float], lam: float,
                             k: int = 3, max_confidence: float = 1.0) -> tuple[dict[int, float], list[float]]:
    """(top-k set, every posterior value sorted descending) of :func:`fuse_reference`."""
    if not meas_set:
        return dict(map_set), sorted(map_set.values(), reverse=True)
    if not map_set:
        return dict(meas_set), sorted(meas_set.values(), reverse=True)
    g, c = dict(map_set), dict(meas_set)
    o1 = max(1.0 - sum(g.values()), 0.0)
    o2 = max(1.0 - sum(c.values()), 0.0)
    if set(g) != set(c):
        for lab in sorted((l for l in g if l not in c), key=lambda l: (-map_set[l], l)):
            c[lab] = lam * o2
            o2 *= 1.0 - lam
        for lab in sorted((l for l in meas_set if l not in map_set), key=lambda l: (-meas_set[l], l)):
            g[lab] = lam * o1
            o1 *= 1.0 - lam
    post = {lab: g[lab] * c[lab] for lab in g}
    total = sum(post.values()) + o1 * o2
    post = {lab: p / total for lab, p in post.items()}
    top = sorted(post.items(), key=lambda kv: (-kv[1], kv[0]))[:k]
    out = {lab: p for lab, p in top if np.float32(p) > 0}
    if out:
        best = max(out, key=out.get)
        out[best] = min(out[best], max_confidence)
    return out, sorted(post.values(), reverse=True)


def as_arrays(s: dict[int, float], k: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """A {label: prob} set as sorted (labels uint16, probs float32) arrays of length k."""
    items = sorted(s.items(), key=lambda kv: (-kv[1], kv[0]))[:k]
    labels = np.full(k, EMPTY, np.uint16)
    probs = np.zeros(k, np.float32)
    for i, (lab, p) in enumerate(items):
        labels[i], probs[i] = lab, p
    return labels, probs


def as_dict(labels: np.ndarray, probs: np.ndarray) -> dict[int, float]:
    return {int(l): float(p) for l, p in zip(labels, probs, strict=True) if l != EMPTY}


def octomap_states(tree, resolution: float) -> dict[tuple[int, int, int], bool]:
    """{finest key: occupied} of a pyoctomap tree, expanding pruned leaves (slow, small trees only)."""
    out = {}
    for leaf in tree.begin_leafs():
        size = leaf.getSize()
        n = max(1, round(size / resolution))
        c = np.asarray(leaf.getCoordinate(), np.float64)
        lo = np.floor((c - size / 2) / resolution + 0.5).astype(np.int64) + 32768
        occ = tree.isNodeOccupied(leaf)
        for dx in range(n):
            for dy in range(n):
                for dz in range(n):
                    out[(int(lo[0] + dx), int(lo[1] + dy), int(lo[2] + dz))] = occ
    return out
