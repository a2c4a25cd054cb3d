"""Median-frequency class balancing (rgbd-semantic-mapping-multiscale-crf, eqs. 1-2; Eigen & Fergus 2015).

F_c = N_c / (P_c W H) (eq. 1): pixels of class c over the pixels of the images in which c appears;
W_c = median_c(F_c) / F_c (eq. 2).  Class 0 (unknown / void) is not trained on and classes that never appear
get weight 0.
"""

from __future__ import annotations

import numpy as np

IGNORE = 0


def median_frequency_weights(labels: np.ndarray, num_classes: int, *, ignore: int = IGNORE) -> np.ndarray:
    """(K,) float32 loss weights from (N, H, W) training labels."""
    labels = np.asarray(labels)
    _, h, w = labels.shape
    pixels = np.zeros(num_classes, np.float64)  # N_c
    images = np.zeros(num_classes, np.float64)  # P_c
    for img in labels:
        counts = np.bincount(img.ravel().astype(np.int64), minlength=num_classes)[:num_classes]
        pixels += counts
        images += counts > 0
    present = images > 0
    present[ignore] = False
    freq = np.zeros(num_classes)
    freq[present] = pixels[present] / (images[present] * h * w)
    weights = np.zeros(num_classes, np.float32)
    if present.any():
        weights[present] = np.median(freq[present]) / freq[present]
    return weights
