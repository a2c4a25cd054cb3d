"""Descriptor matching: guided by predicted projections (grid search, vectorised) or brute force with a ratio test."""

from __future__ import annotations

import cv2
import numpy as np


def hamming(a64: np.ndarray, b64: np.ndarray) -> np.ndarray:
    """Row-wise Hamming distances of two (P, 4) uint64 descriptor arrays."""
    return np.bitwise_count(a64 ^ b64).sum(axis=1, dtype=np.int32)


def _candidate_pairs(proj: np.ndarray, kp_uv: np.ndarray, radius: float,
                     size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """All (projection, keypoint) index pairs closer than ``radius`` pixels, found through a grid of cells."""
    w, h = size
    cell = max(float(radius), 1.0)
    ncol, nrow = int(w // cell) + 1, int(h // cell) + 1
    kc = (np.clip(kp_uv[:, 1] // cell, 0, nrow - 1).astype(np.int64) * ncol
          + np.clip(kp_uv[:, 0] // cell, 0, ncol - 1).astype(np.int64))
    order = np.argsort(kc, kind="stable")
    counts = np.bincount(kc, minlength=ncol * nrow)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    pc = np.floor(proj[:, 0] / cell).astype(np.int64)
    pr = np.floor(proj[:, 1] / cell).astype(np.int64)
    off = np.array([-1, 0, 1])
    cols = (pc[:, None, None] + off[None, None, :]).repeat(3, 1)
    rows = (pr[:, None, None] + off[None, :, None]).repeat(3, 2)
    inside = (cols >= 0) & (cols < ncol) & (rows >= 0) & (rows < nrow)
    cells = np.where(inside, rows * ncol + cols, 0).reshape(len(proj), 9)
    n = np.where(inside.reshape(len(proj), 9), counts[cells], 0).ravel()
    total = int(n.sum())
    if total == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    pi = np.repeat(np.arange(len(proj)), 9)
    pi = np.repeat(pi, n)
    first = np.repeat(starts[cells.ravel()], n)
    within = np.arange(total) - np.repeat(np.cumsum(n) - n, n)
    ki = order[first + within]
    d2 = ((proj[pi] - kp_uv[ki]) ** 2).sum(1)
    keep = d2 <= radius * radius
    return pi[keep], ki[keep]


def best_unique(qi: np.ndarray, ti: np.ndarray, dist: np.ndarray, max_dist: int,
                ratio: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """From candidate pairs keep each query's best (under ``max_dist``, passing the ratio test against its
    second best), then each target's best query only: one-to-one matches ``(query, target, distance)``."""
    if len(qi) == 0:
        return qi, ti, dist
    order = np.lexsort((dist, qi))
    qs, ts, ds = qi[order], ti[order], dist[order]
    first = np.ones(len(qs), bool)
    first[1:] = qs[1:] != qs[:-1]
    idx = np.flatnonzero(first)
    second = idx + 1
    has_second = second < len(qs)
    has_second[has_second] = qs[second[has_second]] == qs[idx[has_second]]
    d1 = ds[idx]
    d2 = np.where(has_second, ds[np.minimum(second, len(qs) - 1)], 1 << 30)
    ok = (d1 <= max_dist) & (d1 < ratio * d2)
    q, t, d = qs[idx][ok], ts[idx][ok], d1[ok]
    # one query per target: the closest in descriptor space
    order = np.lexsort((d, t))
    t_sorted = t[order]
    keep = np.ones(len(order), bool)
    keep[1:] = t_sorted[1:] != t_sorted[:-1]
    sel = order[keep]
    return q[sel], t[sel], d[sel]


def match_projected(proj: np.ndarray, lm_desc64: np.ndarray, kp_uv: np.ndarray, kp_desc64: np.ndarray,
                    radius: float, size: tuple[int, int], max_dist: int,
                    ratio: float) -> tuple[np.ndarray, np.ndarray]:
    """Match projected landmarks to keypoints within ``radius`` pixels: (landmark rows, keypoint rows)."""
    if len(proj) == 0 or len(kp_uv) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    pi, ki = _candidate_pairs(proj, kp_uv, radius, size)
    dist = hamming(lm_desc64[pi], kp_desc64[ki])
    q, t, _ = best_unique(pi, ki, dist, max_dist, ratio)
    return q, t


_BF = cv2.BFMatcher(cv2.NORM_HAMMING)


def match_brute_force(desc_a: np.ndarray, desc_b: np.ndarray, max_dist: int = 80,
                      ratio: float = 0.8) -> tuple[np.ndarray, np.ndarray]:
    """One-to-one matches between two descriptor sets by exhaustive search with Lowe's ratio test."""
    if len(desc_a) < 2 or len(desc_b) < 2:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    knn = _BF.knnMatch(desc_a, desc_b, k=2)
    arr = np.array([(m[0].queryIdx, m[0].trainIdx, m[0].distance, m[1].distance) for m in knn if len(m) == 2])
    if len(arr) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    ok = (arr[:, 2] <= max_dist) & (arr[:, 2] < ratio * arr[:, 3])
    q, t, d = arr[ok, 0].astype(np.int64), arr[ok, 1].astype(np.int64), arr[ok, 2]
    order = np.lexsort((d, t))
    keep = np.ones(len(order), bool)
    keep[1:] = t[order][1:] != t[order][:-1]
    sel = order[keep]
    return q[sel], t[sel]


def count_brute_force(desc_a: np.ndarray, desc_b: np.ndarray, max_dist: int = 64, ratio: float = 0.8) -> int:
    """Number of ratio-test matches between two descriptor sets (a similarity score for place recognition)."""
    return len(match_brute_force(desc_a, desc_b, max_dist, ratio)[0])


def nearest_owner_votes(query: np.ndarray, database: np.ndarray, owner: np.ndarray, n_owners: int,
                        max_dist: int = 64) -> np.ndarray:
    """Place-recognition votes: each query descriptor votes for the owner (e.g. keyframe) of its nearest database
    descriptor when that is within ``max_dist`` bits; one exhaustive search against all owners at once."""
    votes = np.zeros(n_owners, np.int64)
    if len(query) == 0 or len(database) == 0:
        return votes
    matches = _BF.match(np.ascontiguousarray(query), np.ascontiguousarray(database))
    hits = np.array([m.trainIdx for m in matches if m.distance <= max_dist], np.int64)
    if len(hits):
        votes += np.bincount(owner[hits], minlength=n_owners)
    return votes
