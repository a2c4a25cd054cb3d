"""Top-k Bayesian label fusion with an "others" class and penalty λ (Algorithm 1 of the semantic OctoMap paper).

A semantic set holds up to k (label, confidence) pairs sorted by confidence; the rest of the mass,
``others = 1 - sum(confidences)``, stands for every class not in the set.  Fusing two sets:

1. labels of the map set missing from the measurement are added to the measurement, in decreasing
   map confidence, each taking ``λ·others₂`` (and ``others₂ ← (1-λ)·others₂``), and symmetrically;
2. Bayes' rule over the (now equal) label sets and "others" (paper eq. 5: multiply, normalise);
3. keep the k most probable labels, the rest goes back into "others".

When both sets already hold the same labels this is plain Bayes.  ``max_confidence`` < 1 caps the top
confidence (the excess goes to "others") so a voxel can still change its mind, like OctoMap's clamping.

The kernels work on single sets (scalars and small arrays) so that every map type can call them from
its own numba loops; :func:`fuse_topk` is the vectorised convenience wrapper for (N, k) arrays.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from semmap.types import EMPTY_LABEL

#: Indices of the settings in a rule kernel's ``params`` vector (``FusionParams.kernel_params``); the K prior
#: log-odds start at ``P_PRIOR``.
P_LAM, P_MAX_CONFIDENCE, P_CLAMP, P_VOTE_CAP, P_PRIOR = 0, 1, 2, 3, 4

EMPTY = int(EMPTY_LABEL)
#: Default penalty λ: share of "others" given to a label that one set lacks (paper: "close to 1").
DEFAULT_LAMBDA = 0.9
#: Default cap on the top confidence after fusion (1.0 = no cap).
DEFAULT_MAX_CONFIDENCE = 0.999
#: Below this total posterior mass the sets are taken as contradictory and the measurement wins.
MIN_POSTERIOR_MASS = 1e-30
#: Largest set size k a map may keep (a set of ``MAX_SET`` pairs fits the paper's inline storage).
MAX_SET = 8
#: Width of :func:`fuse_sets`' scratch rows: the union of two sets of at most :data:`MAX_SET` labels.  The one place
#: this number is written; :func:`semmap.fusion.dispatch.new_scratch` allocates it.
SCRATCH = 2 * MAX_SET


@nb.njit(cache=True, inline="always")
def _find(labels: np.ndarray, n: int, lab: int) -> int:
    for i in range(n):
        if labels[i] == lab:
            return i
    return -1


@nb.njit(cache=True)
def fuse_sets(map_labels: np.ndarray, map_probs: np.ndarray,
              meas_labels: np.ndarray, meas_probs: np.ndarray,
              lam: float, max_confidence: float,
              out_labels: np.ndarray, out_probs: np.ndarray,
              scratch_i: np.ndarray, scratch_f: np.ndarray) -> None:
    """Fuse one measurement set into one map set (Algorithm 1 + Bayes + top-k); writes ``out_*``.

    All arrays have length k; empty slots hold :data:`EMPTY_LABEL` with probability 0.  ``out_*`` may
    alias ``map_*``.  An empty map set simply takes the measurement.  ``scratch_*`` come from
    :func:`semmap.fusion.dispatch.new_scratch` (no allocation in the hot loop).
    """
    k = map_labels.shape[0]
    lab = scratch_i[0]  # union of labels
    extra = scratch_i[1]  # measurement labels the map lacks
    flag = scratch_i[2]
    c1 = scratch_f[0]  # map confidence per union label
    c2 = scratch_f[1]  # measurement confidence per union label
    extra_p = scratch_f[2]
    n = 0
    s1 = 0.0
    for i in range(k):
        if map_labels[i] != EMPTY:
            lab[n] = map_labels[i]
            c1[n] = map_probs[i]
            c2[n] = -1.0  # "absent from the measurement" until found below
            s1 += map_probs[i]
            n += 1
    n1 = n
    s2 = 0.0
    n_extra = 0
    for i in range(k):
        m = meas_labels[i]
        if m == EMPTY:
            continue
        s2 += meas_probs[i]
        j = _find(lab, n1, m)
        if j >= 0:
            c2[j] = meas_probs[i]
        else:
            extra[n_extra] = m
            extra_p[n_extra] = meas_probs[i]
            n_extra += 1
    n2 = n1 - _count_negative(c2, n1) + n_extra
    if n2 == 0:  # nothing measured: keep the map as it is
        for i in range(k):
            out_labels[i] = map_labels[i]
            out_probs[i] = map_probs[i]
        return
    if n1 == 0:  # first observation of this voxel
        for i in range(k):
            out_labels[i] = meas_labels[i]
            out_probs[i] = meas_probs[i]
        return
    o1 = max(1.0 - s1, 0.0)
    o2 = max(1.0 - s2, 0.0)

    # Lines 9-13: map labels absent from the measurement, by decreasing map confidence (ties: map order).
    while True:
        best = -1
        for j in range(n1):
            if c2[j] < 0.0 and (best < 0 or c1[j] > c1[best]):
                best = j
        if best < 0:
            break
        c2[best] = lam * o2
        o2 = (1.0 - lam) * o2

    # Lines 14-18: measurement labels absent from the map, by decreasing measurement confidence
    # (ties: in the measurement's order, i.e. smaller label id first for sets sorted like ours).
    for j in range(n_extra):
        flag[j] = 0
    for _ in range(n_extra):
        best = -1
        for j in range(n_extra):
            if flag[j] == 0 and (best < 0 or extra_p[j] > extra_p[best]):
                best = j
        flag[best] = 1
        lab[n] = extra[best]
        c2[n] = extra_p[best]
        c1[n] = lam * o1
        o1 = (1.0 - lam) * o1
        n += 1

    # Bayes (eq. 5) over the common label set and "others".
    total = o1 * o2
    for j in range(n):
        c1[j] = c1[j] * c2[j]
        total += c1[j]
    if total <= MIN_POSTERIOR_MASS:  # contradictory certainties: restart from the measurement
        for i in range(k):
            out_labels[i] = meas_labels[i]
            out_probs[i] = meas_probs[i]
        return
    for j in range(n):
        c1[j] /= total

    # Keep the k most probable (ties: smaller label id first, for determinism).
    for i in range(k):
        best = -1
        for j in range(n):
            if c1[j] >= 0.0 and (best < 0 or c1[j] > c1[best] or (c1[j] == c1[best] and lab[j] < lab[best])):
                best = j
        if best < 0 or np.float32(c1[best]) <= 0.0:  # nothing left that float32 can hold
            for r in range(i, k):
                out_labels[r] = EMPTY
                out_probs[r] = 0.0
            break
        out_labels[i] = lab[best]
        out_probs[i] = c1[best]
        c1[best] = -1.0
    if out_probs[0] > max_confidence:
        out_probs[0] = max_confidence


@nb.njit(cache=True, inline="always")
def _count_negative(a: np.ndarray, n: int) -> int:
    c = 0
    for i in range(n):
        if a[i] < 0.0:
            c += 1
    return c


@nb.njit(cache=True)
def topk_fuse(labels: np.ndarray, values: np.ndarray, meas_labels: np.ndarray, meas_probs: np.ndarray,
              params: np.ndarray) -> bool:
    """The ``topk`` rule in the dispatcher's form (:data:`semmap.fusion.dispatch.UPDATE_SIG`): Algorithm 1 in place."""
    si, sf = np.empty((3, SCRATCH), np.int64), np.empty((3, SCRATCH), np.float64)
    fuse_sets(labels, values, meas_labels, meas_probs, params[P_LAM], params[P_MAX_CONFIDENCE], labels, values, si, sf)
    return True


@nb.njit(cache=True)
def _fuse_rows(map_labels, map_probs, meas_labels, meas_probs, lam, max_confidence, out_labels, out_probs):
    si, sf = np.empty((3, SCRATCH), np.int64), np.empty((3, SCRATCH), np.float64)
    for r in range(map_labels.shape[0]):
        fuse_sets(map_labels[r], map_probs[r], meas_labels[r], meas_probs[r], lam, max_confidence,
                  out_labels[r], out_probs[r], si, sf)


def fuse_topk(map_labels: np.ndarray, map_probs: np.ndarray, meas_labels: np.ndarray, meas_probs: np.ndarray,
              *, lam: float = DEFAULT_LAMBDA, max_confidence: float = DEFAULT_MAX_CONFIDENCE
              ) -> tuple[np.ndarray, np.ndarray]:
    """Fuse (N, k) measurement sets into (N, k) map sets row by row; returns new (labels, probs).

    Labels uint16 (:data:`EMPTY_LABEL` for unused slots), probabilities float32 sorted descending.
    """
    if not 0.0 <= lam <= 1.0:
        raise ValueError(f"λ must be in [0, 1], got {lam}")
    if not 0.0 < max_confidence <= 1.0:
        raise ValueError(f"max_confidence must be in (0, 1], got {max_confidence}")
    ml = np.ascontiguousarray(np.atleast_2d(map_labels), dtype=np.uint16)
    mp = np.ascontiguousarray(np.atleast_2d(map_probs), dtype=np.float32)
    zl = np.ascontiguousarray(np.atleast_2d(meas_labels), dtype=np.uint16)
    zp = np.ascontiguousarray(np.atleast_2d(meas_probs), dtype=np.float32)
    if not (ml.shape == mp.shape == zl.shape == zp.shape):
        raise ValueError(f"semantic set shapes differ: {ml.shape} {mp.shape} {zl.shape} {zp.shape}")
    if ml.shape[1] > MAX_SET:
        raise ValueError(f"top-k fusion supports k <= {MAX_SET}, got {ml.shape[1]}")
    out_l = np.empty_like(ml)
    out_p = np.empty_like(mp)
    _fuse_rows(ml, mp, zl, zp, float(lam), float(max_confidence), out_l, out_p)
    return out_l, out_p
