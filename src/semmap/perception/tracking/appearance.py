"""Appearance descriptors of instance masks for tracking: colour histograms, when the source gives no features.

DeepSORT compares a re-identification network's features by cosine distance. Without such a network, each mask's
colours are counted in a coarse RGB histogram (``BINS_PER_CHANNEL``^3 bins, every ``PIXEL_STRIDE``-th pixel) in
one ``bincount`` over the whole image, and the square root of the normalised counts is used (its dot product is
the Bhattacharyya coefficient), so cosine distance compares colour distributions.
"""

from __future__ import annotations

import numpy as np

BINS_PER_CHANNEL = 4
PIXEL_STRIDE = 2


def colour_histograms(rgb: np.ndarray, ids: np.ndarray, n: int) -> np.ndarray:
    """(n, BINS_PER_CHANNEL^3) float32 unit-length sqrt colour histograms of masks 1..n of id image ``ids``."""
    bins = BINS_PER_CHANNEL**3
    if n == 0:
        return np.zeros((0, bins), np.float32)
    img = rgb[::PIXEL_STRIDE, ::PIXEL_STRIDE].astype(np.int64)
    sub = ids[::PIXEL_STRIDE, ::PIXEL_STRIDE].astype(np.int64)
    shift = 8 - int(np.log2(BINS_PER_CHANNEL))
    q = ((img[..., 0] >> shift) * BINS_PER_CHANNEL + (img[..., 1] >> shift)) * BINS_PER_CHANNEL + (img[..., 2] >> shift)
    counts = np.bincount((sub * bins + q).ravel(), minlength=(n + 1) * bins).reshape(n + 1, bins)[1:]
    hist = np.sqrt(counts.astype(np.float32))
    norm = np.linalg.norm(hist, axis=1, keepdims=True)
    return np.where(norm > 0, hist / np.maximum(norm, 1e-12), 0.0).astype(np.float32)
