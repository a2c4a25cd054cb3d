"""Temperature scaling of a segmenter's class probabilities (Guo et al. 2017), applied before fusion: one scalar T
per network, fitted on validation images by negative log-likelihood (:mod:`semmap.train.calibrate`) and stored with
its weights (a trained network divides its logits by it), or ``semmap run --temperature T``.

``softmax(z / T)`` is ``p^(1/T)`` renormalised, with ``p = softmax(z)``: the probabilities a segmenter produces can
be re-tempered without its logits. ``T > 1`` softens an over-confident network, ``T < 1`` sharpens, ``T = 1`` is the
identity; the order of the classes (and so every argmax) never changes.

Two inputs, the two forms segmenters produce:

- a full (..., K) probability array (``NetworkSegmenter.probabilities``): exact;
- a :class:`~semmap.types.TopKProbs` set (what a run fuses): the k kept pairs are exact relative to each other;
  the "others" mass ``1 - sum(top-k)`` is taken as spread evenly over the ``num_classes - k`` classes not kept
  (``num_classes`` None: as one lump, exact where nothing is left over). Rows without classes stay as they are.
"""

from __future__ import annotations

import numpy as np

from semmap.errors import ConfigError
from semmap.limits import check
from semmap.types import EMPTY_LABEL, TopKProbs


def check_temperature(temperature: float) -> float:
    """``temperature`` as a float when it is a finite number within the ``temperature`` limit of
    ``semmap.limits``, else a one-line ConfigError."""
    return float(check("temperature", temperature, "temperature"))


def apply_temperature(probabilities, temperature: float, *, num_classes: int | None = None):
    """``probabilities`` (a (..., K) array summing to 1 over the last axis, or a :class:`TopKProbs`) tempered as
    ``softmax(log p / T)``; the same form, dtype and shape back, the class order unchanged (see the module
    docstring for the top-k sets' "others" mass)."""
    t = check_temperature(temperature)
    if isinstance(probabilities, TopKProbs):
        return probabilities if t == 1.0 else _tempered_topk(probabilities, t, num_classes)
    p = np.asarray(probabilities)
    if t == 1.0:
        return p
    if p.ndim == 0 or p.shape[-1] == 0:
        raise ConfigError(f"class probabilities must have a class axis, got shape {p.shape}")
    logp = _log(p.astype(np.float64))
    q = _softmax_rows(logp / t, np.zeros(p.shape[:-1]), np.zeros(p.shape[:-1]))[0]
    return q.astype(p.dtype if p.dtype.kind == "f" else np.float32)


def _log(p: np.ndarray) -> np.ndarray:
    """log p with -inf where p is 0 (or negative: a damaged entry carries no mass)."""
    out = np.full(p.shape, -np.inf)
    np.log(p, out=out, where=p > 0)
    return out


def _softmax_rows(z: np.ndarray, z_rest: np.ndarray, n_rest: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Normalise ``exp(z)`` (..., K) together with ``n_rest`` more classes of log-weight ``z_rest`` each (...);
    (the K probabilities, the rest's total). A row of nothing but -inf gives zeros."""
    rest = np.where(n_rest > 0, z_rest, -np.inf)
    top = np.maximum(z.max(axis=-1) if z.shape[-1] else -np.inf, rest)
    top = np.where(np.isfinite(top), top, 0.0)
    e = np.exp(z - top[..., None])
    e_rest = np.where(n_rest > 0, n_rest * np.exp(rest - top), 0.0)
    total = e.sum(axis=-1) + e_rest
    safe = np.where(total > 0, total, 1.0)
    return e / safe[..., None], e_rest / safe


def _tempered_topk(sets: TopKProbs, t: float, num_classes: int | None) -> TopKProbs:
    """Top-k sets tempered with the "others" mass spread over the classes not kept (one lump without a count)."""
    p = np.asarray(sets.probs, np.float64)
    kept = (np.asarray(sets.labels) != EMPTY_LABEL) & (p > 0)
    p = np.where(kept, p, 0.0)
    others = np.clip(1.0 - p.sum(axis=-1), 0.0, 1.0)
    n_rest = (np.ones(p.shape[:-1]) if num_classes is None
              else np.maximum(int(num_classes) - kept.sum(axis=-1), 0).astype(np.float64))
    has_rest = (others > 1e-12) & (n_rest > 0)
    share = np.where(has_rest, others / np.where(has_rest, n_rest, 1.0), 1.0)
    q, _ = _softmax_rows(_log(p) / t, np.log(share) / t, np.where(has_rest, n_rest, 0.0))
    empty = ~kept.any(axis=-1)  # no class in the set: nothing to temper (all mass is "others")
    q[empty] = p[empty]
    return TopKProbs(sets.labels, q.astype(np.asarray(sets.probs).dtype))
