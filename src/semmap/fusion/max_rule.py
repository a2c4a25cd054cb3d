"""The ``max`` rule: a voxel keeps one (label, confidence) pair and the more confident of map and measurement wins.

The baseline of semantic_slam-style OctoMaps (RS-SLAM's "max confidence fusion"): a measurement whose most
probable class agrees with the voxel's raises the confidence to the larger of the two; a disagreeing one
replaces the voxel's pair only when it is more confident.  ``max_confidence`` < 1 caps the stored confidence,
so a certain measurement (confidence 1) can always still change the class.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from semmap.fusion.topk_bayes import DEFAULT_MAX_CONFIDENCE, P_MAX_CONFIDENCE
from semmap.types import EMPTY_LABEL

EMPTY = int(EMPTY_LABEL)


@nb.njit(cache=True, inline="always")
def max_update(map_label: int, map_conf: float, meas_label: int, meas_conf: float,
               max_confidence: float) -> tuple[int, float]:
    """New (label, confidence) of a voxel after one measurement's top class (EMPTY label: no change)."""
    if meas_label == EMPTY:
        return map_label, map_conf
    c = min(meas_conf, max_confidence)
    if map_label == EMPTY or (meas_label != map_label and meas_conf > map_conf):
        return meas_label, c
    if meas_label == map_label:
        return map_label, max(map_conf, c)
    return map_label, map_conf


@nb.njit(cache=True, inline="always")
def max_fuse(labels: np.ndarray, values: np.ndarray, meas_labels: np.ndarray, meas_probs: np.ndarray,
             params: np.ndarray) -> bool:
    """The ``max`` rule in the dispatcher's form (:data:`semmap.fusion.dispatch.UPDATE_SIG`): one pair in place."""
    lab, conf = max_update(labels[0], values[0], meas_labels[0], meas_probs[0], params[P_MAX_CONFIDENCE])
    labels[0] = lab
    values[0] = conf
    return True


@nb.njit(cache=True)
def _max_rows(map_labels, map_conf, meas_labels, meas_probs, max_confidence):
    for r in range(map_labels.shape[0]):
        lab, conf = max_update(map_labels[r], map_conf[r], meas_labels[r, 0], meas_probs[r, 0], max_confidence)
        map_labels[r] = lab
        map_conf[r] = conf


def fuse_max(map_labels: np.ndarray, map_conf: np.ndarray, meas_labels: np.ndarray, meas_probs: np.ndarray, *,
             max_confidence: float = DEFAULT_MAX_CONFIDENCE) -> tuple[np.ndarray, np.ndarray]:
    """Fuse (N, k) measurements (their top class) into (N,) voxel pairs; returns new (labels, confidences)."""
    lab = np.array(np.atleast_1d(map_labels), dtype=np.uint16)
    conf = np.array(np.atleast_1d(map_conf), dtype=np.float32)
    zl = np.ascontiguousarray(np.atleast_2d(meas_labels), dtype=np.uint16)
    zp = np.ascontiguousarray(np.atleast_2d(meas_probs), dtype=np.float32)
    if not (lab.shape == conf.shape == zl.shape[:1] == zp.shape[:1]) or zl.shape != zp.shape:
        raise ValueError(f"shapes differ: {lab.shape} {conf.shape} {zl.shape} {zp.shape}")
    if not 0.0 < max_confidence <= 1.0:
        raise ValueError(f"max_confidence must be in (0, 1], got {max_confidence}")
    _max_rows(lab, conf, zl, zp, float(max_confidence))
    return lab, conf
