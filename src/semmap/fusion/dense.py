"""Full-K fusion rules: recursive multi-class Bayes in log-odds (with or without the class prior) and voting.

``bayes`` (*semantic-voxel-grid-mcl* eqs. 2-5): a voxel keeps ``h`` (K,), the log-odds of every class against a
pivot class (eq. 3); a measurement z with class probabilities p(c|z) adds ``l(z) - h0`` where
``l(z) = log p(c|z) - log p(pivot|z)`` (eqs. 4-5) and ``h0`` is the prior's log-odds (0 for a uniform prior);
eq. 2 sums this over every measurement (every pixel) that falls in the voxel.

``bayes-prior`` (*rgbd-semantic-mapping-multiscale-crf* eqs. 3-5): the same recursion with each measurement
divided by the class prior p(c), i.e. ``h0 = log p(c) - log p(pivot)``.

The pivot is arbitrary (eq. 5's note): log-odds against one class differ from those against another by a
constant, so after each update the kernels shift ``h`` so that its largest entry is 0 (the pivot becomes the
voxel's most probable class) and clamp it below at ``-clamp``.  The numbers then stay small enough for float16,
and the clamp plays OctoMap's role: no class is ever more than ``exp(clamp)`` times likelier than another, so
enough contrary evidence still changes a voxel's class.

``vote`` keeps K counts of argmax labels, halved once the largest exceeds a cap.

All kernels work on one voxel's state (float32 scratch of length K) and one top-k measurement, so every map
calls them from its own numba loops; ``fuse_bayes`` / ``fuse_vote`` are the vectorised wrappers for (N, ...)
arrays.  K comes from the array shapes at run time.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from semmap.fusion.rules import DEFAULT_LOGODDS_CLAMP, DEFAULT_VOTE_CAP
from semmap.fusion.topk_bayes import P_CLAMP, P_PRIOR, P_VOTE_CAP
from semmap.types import EMPTY_LABEL

EMPTY = int(EMPTY_LABEL)
#: Smallest probability a measurement gives any class (a zero would veto a class forever).
MIN_PROB = 1e-4
_LOG_MIN_PROB = math.log(MIN_PROB)


@nb.njit(cache=True, inline="always")
def others_share(labels: np.ndarray, probs: np.ndarray, num_classes: int) -> float:
    """Probability of each class outside a top-k set: the "others" mass spread evenly over the K - n
    classes not in the set (n = labels present), at least :data:`MIN_PROB`."""
    n = 0
    s = 0.0
    for j in range(labels.shape[0]):
        if labels[j] != EMPTY:
            n += 1
            s += probs[j]
    rest = num_classes - n
    q = max(1.0 - s, 0.0) / rest if rest > 0 else 0.0
    return max(q, MIN_PROB)


@nb.njit(cache=True, inline="always")
def bayes_add(h: np.ndarray, labels: np.ndarray, probs: np.ndarray) -> bool:
    """``h += l(z)`` for one top-k measurement, up to a constant (eqs. 4-5): only the set's classes move,
    by ``log p(c|z) - log q`` with q the share of each class outside the set.  False if the set is empty."""
    K = h.shape[0]
    q = others_share(labels, probs, K)
    log_q = math.log(q)
    seen = False
    for j in range(labels.shape[0]):
        c = labels[j]
        if c != EMPTY and c < K:
            h[c] += math.log(max(probs[j], MIN_PROB)) - log_q
            seen = True
    return seen


@nb.njit(cache=True, inline="always")
def subtract_prior(h: np.ndarray, prior_log: np.ndarray, times: float) -> None:
    """``h -= times * h0`` (eq. 2's ``- h0`` for ``times`` measurements; eq. 5's division by p(c))."""
    for c in range(h.shape[0]):
        h[c] -= times * prior_log[c]


@nb.njit(cache=True, inline="always")
def normalise_logodds(h: np.ndarray, clamp: float) -> None:
    """Shift ``h`` so its largest entry is 0 (pivot = most probable class) and floor it at ``-clamp``."""
    top = h[0]
    for c in range(1, h.shape[0]):
        if h[c] > top:
            top = h[c]
    for c in range(h.shape[0]):
        v = h[c] - top
        h[c] = -clamp if v < -clamp else v


@nb.njit(cache=True)
def bayes_update(h: np.ndarray, labels: np.ndarray, probs: np.ndarray, prior_log: np.ndarray,
                 clamp: float) -> None:
    """One measurement into one voxel (eq. 2 with a single z): add, divide by the prior, normalise, clamp."""
    if bayes_add(h, labels, probs):
        subtract_prior(h, prior_log, 1.0)
        normalise_logodds(h, clamp)


@nb.njit(cache=True, inline="always")
def vote_add(counts: np.ndarray, labels: np.ndarray) -> bool:
    """One vote for the measurement's most probable class (its first label)."""
    c = labels[0]
    if c == EMPTY or c >= counts.shape[0]:
        return False
    counts[c] += 1.0
    return True


@nb.njit(cache=True, inline="always")
def normalise_votes(counts: np.ndarray, cap: float) -> None:
    """Halve every count while the largest exceeds ``cap`` (old votes fade; float16 counts stay exact)."""
    while True:
        top = 0.0
        for c in range(counts.shape[0]):
            top = max(top, counts[c])
        if top <= cap:
            return
        for c in range(counts.shape[0]):
            counts[c] = math.floor(counts[c] * 0.5)


@nb.njit(cache=True, inline="always")
def dense_top(state: np.ndarray, logodds: bool) -> tuple[int, float, float]:
    """(most probable class, its probability, entropy in nats) of a dense state: log-odds (softmax) or counts.
    A state with no evidence (all equal) still names its lowest class; callers keep an "observed" flag."""
    K = state.shape[0]
    best = 0
    for c in range(1, K):
        if state[c] > state[best]:
            best = c
    if logodds:
        z = 0.0
        for c in range(K):
            z += math.exp(state[c] - state[best])
        ent = 0.0
        for c in range(K):
            p = math.exp(state[c] - state[best]) / z
            if p > 0.0:
                ent -= p * math.log(p)
        return best, 1.0 / z, ent
    total = 0.0
    for c in range(K):
        total += state[c]
    if total <= 0.0:
        return best, 0.0, 0.0
    ent = 0.0
    for c in range(K):
        p = state[c] / total
        if p > 0.0:
            ent -= p * math.log(p)
    return best, state[best] / total, ent


# ------------------------------------------------------------------ the rules in the dispatcher's form
# (``semmap.fusion.dispatch.UPDATE_SIG`` / ``FINISH_SIG``; the dispatcher inlines the same steps for these rules)
@nb.njit(cache=True)
def bayes_fuse(labels: np.ndarray, values: np.ndarray, meas_labels: np.ndarray, meas_probs: np.ndarray,
               params: np.ndarray) -> bool:
    """``bayes`` / ``bayes-prior`` update: eq. 2's sum over one measurement (:func:`bayes_add`)."""
    return bayes_add(values, meas_labels, meas_probs)


@nb.njit(cache=True)
def bayes_finish(labels: np.ndarray, values: np.ndarray, n: int, params: np.ndarray) -> None:
    """``bayes`` after a frame's measurements of a voxel: normalise and clamp."""
    normalise_logodds(values, params[P_CLAMP])


@nb.njit(cache=True)
def bayes_prior_finish(labels: np.ndarray, values: np.ndarray, n: int, params: np.ndarray) -> None:
    """``bayes-prior`` after a frame's ``n`` measurements of a voxel: divide by the prior n times, normalise."""
    subtract_prior(values, params[P_PRIOR:], np.float64(n))
    normalise_logodds(values, params[P_CLAMP])


@nb.njit(cache=True)
def vote_fuse(labels: np.ndarray, values: np.ndarray, meas_labels: np.ndarray, meas_probs: np.ndarray,
              params: np.ndarray) -> bool:
    """``vote`` update: one vote for the measurement's top class."""
    return vote_add(values, meas_labels)


@nb.njit(cache=True)
def vote_finish(labels: np.ndarray, values: np.ndarray, n: int, params: np.ndarray) -> None:
    """``vote`` after a frame: halve the counts while the largest is past the cap."""
    normalise_votes(values, params[P_VOTE_CAP])


# ---------------------------------------------------------------------------------------------- wrappers
def expand_topk(labels: np.ndarray, probs: np.ndarray, num_classes: int) -> np.ndarray:
    """(N, K) probabilities of (N, k) top-k sets as the full-K rules read them: the set's probabilities on its
    classes, the "others" mass spread evenly over the rest, every entry at least :data:`MIN_PROB`."""
    labels = np.atleast_2d(np.asarray(labels, np.int64))
    probs = np.atleast_2d(np.asarray(probs, np.float64))
    present = (labels != EMPTY) & (labels < num_classes)
    n = present.sum(1)
    rest = num_classes - n
    others = np.clip(1.0 - np.where(present, probs, 0.0).sum(1), 0.0, None)
    q = np.where(rest > 0, others / np.maximum(rest, 1), 0.0)
    out = np.repeat(np.maximum(q, MIN_PROB)[:, None], num_classes, axis=1)
    rows = np.nonzero(present)
    out[rows[0], labels[rows]] = np.maximum(probs[rows], MIN_PROB)
    return out


def _checked(state: np.ndarray, labels: np.ndarray, probs: np.ndarray):
    st = np.array(np.atleast_2d(state), dtype=np.float32, order="C")
    lab = np.ascontiguousarray(np.atleast_2d(labels), dtype=np.uint16)
    pr = np.ascontiguousarray(np.atleast_2d(probs), dtype=np.float32)
    if lab.shape != pr.shape or lab.shape[0] != st.shape[0]:
        raise ValueError(f"state {st.shape}, labels {lab.shape} and probs {pr.shape} do not match")
    return st, lab, pr


@nb.njit(cache=True)
def _bayes_rows(state, labels, probs, prior_log, clamp):
    for r in range(state.shape[0]):
        bayes_update(state[r], labels[r], probs[r], prior_log, clamp)


@nb.njit(cache=True)
def _vote_rows(state, labels, cap):
    for r in range(state.shape[0]):
        if vote_add(state[r], labels[r]):
            normalise_votes(state[r], cap)


def fuse_bayes(state: np.ndarray, labels: np.ndarray, probs: np.ndarray, *, prior_log: np.ndarray | None = None,
               clamp: float = DEFAULT_LOGODDS_CLAMP) -> np.ndarray:
    """Fuse (N, k) measurements into (N, K) log-odds states row by row; returns the new states (float32).
    ``prior_log`` (K,) is ``h0`` (None: uniform prior = ``bayes``; log class priors = ``bayes-prior``)."""
    st, lab, pr = _checked(state, labels, probs)
    h0 = np.zeros(st.shape[1], np.float32) if prior_log is None else np.ascontiguousarray(prior_log, np.float32)
    if h0.shape != (st.shape[1],):
        raise ValueError(f"prior has {h0.shape} entries, states {st.shape[1]} classes")
    _bayes_rows(st, lab, pr, h0, float(clamp))
    return st


def fuse_vote(state: np.ndarray, labels: np.ndarray, probs: np.ndarray, *,
              cap: float = DEFAULT_VOTE_CAP) -> np.ndarray:
    """Add each (N, k) measurement's argmax vote to (N, K) counts; returns the new counts (float32)."""
    st, lab, _ = _checked(state, labels, probs)
    _vote_rows(st, lab, float(cap))
    return st


def logodds_to_probs(h: np.ndarray) -> np.ndarray:
    """(..., K) log-odds against any pivot -> class probabilities (softmax)."""
    h = np.asarray(h, np.float64)
    e = np.exp(h - h.max(axis=-1, keepdims=True))
    return e / e.sum(axis=-1, keepdims=True)


def votes_to_probs(counts: np.ndarray) -> np.ndarray:
    """(..., K) vote counts -> class frequencies (uniform where nothing was voted)."""
    c = np.asarray(counts, np.float64)
    total = c.sum(axis=-1, keepdims=True)
    return np.where(total > 0, c / np.where(total > 0, total, 1.0), 1.0 / c.shape[-1])
