"""The PASCAL VOC 2012 label set (21 classes) that the pretrained ESPNetv2 segmentation weights predict.

Id 0 is VOC's "background". semmap's convention is that label 0 means "unknown / void", so a pixel the network calls
background is treated as void (no object evidence), which is what we want for a kitchen whose walls, floor and
counters have no VOC class. The name stays "background" so that it matches the VOC literature.
"""

from __future__ import annotations

import numpy as np

from semmap.types import LabelSet


def voc_palette(n: int = 21) -> np.ndarray:
    """The standard PASCAL VOC colour map (bit-interleaved id -> RGB) for ids 0..n-1, as (n, 3) uint8."""
    colors = np.zeros((n, 3), np.uint8)
    for i in range(n):
        c, r, g, b = i, 0, 0, 0
        for shift in range(7, -1, -1):
            r |= (c & 1) << shift
            g |= ((c >> 1) & 1) << shift
            b |= ((c >> 2) & 1) << shift
            c >>= 3
        colors[i] = (r, g, b)
    return colors


#: VOC class names, index = class id (0 = background, which semmap treats as unknown / void).
VOC_NAMES: tuple[str, ...] = (
    "background", "aeroplane", "bicycle", "bird", "boat", "bottle", "bus", "car", "cat", "chair", "cow",
    "diningtable", "dog", "horse", "motorbike", "person", "pottedplant", "sheep", "sofa", "train", "tvmonitor",
)

#: PASCAL VOC label set with the standard palette (no entry is pure white; background is black).
PASCAL_VOC = LabelSet(VOC_NAMES, voc_palette(len(VOC_NAMES)))
