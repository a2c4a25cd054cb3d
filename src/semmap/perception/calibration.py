"""Temperature scaling of class probabilities (Guo et al. 2017): ``softmax(logits / T)`` with one scalar T per
network, fitted on validation images by negative log-likelihood (:mod:`semmap.train.calibrate`) and stored with
its weights, so that a pixel's 0.8 means right 8 times in 10 - what the map's fusion rules assume."""

from __future__ import annotations

import numpy as np


def apply_temperature(probabilities: np.ndarray, temperature: float) -> np.ndarray:
    """Probabilities (classes on the last axis) rescaled by temperature T: ``softmax(log(p) / T)``, which is
    ``softmax(logits / T)`` for ``p = softmax(logits)``; T = 1 returns them unchanged (as float32)."""
    if not (np.isfinite(temperature) and temperature > 0):
        raise ValueError(f"temperature must be a positive number, got {temperature}")
    p = np.asarray(probabilities, np.float32)
    if temperature == 1.0:
        return p
    with np.errstate(divide="ignore"):
        z = np.log(np.maximum(p, 0.0)) / np.float32(temperature)
    z -= z.max(axis=-1, keepdims=True)
    e = np.exp(z)
    return e / e.sum(axis=-1, keepdims=True)
