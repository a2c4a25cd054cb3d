"""Appearance descriptors of instance masks for tracking: colour histograms, when the source gives no features.

DeepSORT compares a re-identification network's features by cosine distance. Without such a network, each mask's
colours are counted in a coarse RGB histogram (``BINS_PER_CHANNEL``^3 bins, every ``PIXEL_STRIDE``-th pixel) in
one numba pass over the whole image, and the square root of the normalised counts is used (its dot product is
the Bhattacharyya coefficient), so cosine distance compares colour distributions.
"""

from __future__ import annotations

import numba as nb
import numpy as np

BINS_PER_CHANNEL = 4
PIXEL_STRIDE = 2


def colour_histograms(rgb: np.ndarray, ids: np.ndarray, n: int) -> np.ndarray:
    """(n, BINS_PER_CHANNEL^3) float32 unit-length sqrt colour histograms of masks 1..n of id image ``ids``."""
    bins = BINS_PER_CHANNEL**3
    if n == 0:
        return np.zeros((0, bins), np.float32)
    shift = 8 - int(np.log2(BINS_PER_CHANNEL))
    counts = _mask_colour_counts(np.asarray(rgb), np.asarray(ids), n, PIXEL_STRIDE, BINS_PER_CHANNEL, shift)
    hist = np.sqrt(counts.astype(np.float32))
    norm = np.linalg.norm(hist, axis=1, keepdims=True)
    return np.where(norm > 0, hist / np.maximum(norm, 1e-12), 0.0).astype(np.float32)


@nb.njit(cache=True)
def _mask_colour_counts(rgb: np.ndarray, ids: np.ndarray, n: int, stride: int, bins_per_channel: int,
                        shift: int) -> np.ndarray:
    """(n, bins^3) int64 counts of each mask's quantised colours over every ``stride``-th pixel (ids outside
    1..n are ignored)."""
    counts = np.zeros((n, bins_per_channel**3), np.int64)
    for v in range(0, ids.shape[0], stride):
        for u in range(0, ids.shape[1], stride):
            k = ids[v, u]
            if k < 1 or k > n:
                continue
            q = ((rgb[v, u, 0] >> shift) * bins_per_channel + (rgb[v, u, 1] >> shift)) * bins_per_channel \
                + (rgb[v, u, 2] >> shift)
            counts[k - 1, q] += 1
    return counts
