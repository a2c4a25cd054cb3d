"""The one seam between the maps and the fusion rules: numba kernels that fuse one voxel's state with one measurement.

Every map kernel (OctoMap insertion and coarsening, voxel grid, point map) holds a voxel's state in working form,
``labels`` (S,) uint16 and ``values`` (W,) float32, and calls :func:`fuse_measurement` once per measurement,
:func:`finish_voxel` once per voxel and frame after its measurements, and :func:`merge_voxel` to fold a child's state
into its parent.  A rule's state has one of three layouts:

* ``set``: S = W (label, confidence) pairs sorted by confidence (``topk``, ``max``);
* ``logodds``: W = K log-odds, S = 0 (``bayes``, ``bayes-prior``);
* ``counts``: W = K counts, S = 0 (``vote``).

The rule is picked by its entry (:mod:`semmap.fusion.registry`): ``code`` selects the inlined kernel of a built-in
rule, and any other rule (:data:`GENERIC`) is called through its compiled ``update`` / ``finish`` functions, passed
to the map kernels as first-class function values of the signatures :data:`UPDATE_SIG` / :data:`FINISH_SIG` (so
the map kernels compile once, whatever the rule).  ``params`` is :meth:`FusionParams.kernel_params`: the settings
at the ``P_*`` indices, then the K prior log-odds.
"""

from __future__ import annotations

import numba as nb
import numpy as np
from numba import types

from semmap.fusion.dense import bayes_add, normalise_logodds, normalise_votes, subtract_prior, vote_add
from semmap.fusion.max_rule import max_fuse
from semmap.fusion.topk_bayes import P_CLAMP, P_LAM, P_MAX_CONFIDENCE, P_PRIOR, P_VOTE_CAP, SCRATCH, fuse_sets

#: Built-in rules' fast paths in the dispatcher; ``GENERIC`` calls the rule's own compiled functions.
GENERIC, MAX_CODE, TOPK_CODE, BAYES_CODE, BAYES_PRIOR_CODE, VOTE_CODE = -1, 0, 1, 2, 3, 4
#: State layouts (see the module docstring).
LAYOUT_SET, LAYOUT_LOGODDS, LAYOUT_COUNTS = 0, 1, 2
__all__ = ["FINISH_SIG", "GENERIC", "P_CLAMP", "P_LAM", "P_MAX_CONFIDENCE", "P_PRIOR", "P_VOTE_CAP", "SCRATCH",
           "UPDATE_SIG", "finish_voxel", "fuse_measurement", "merge_voxel", "new_scratch"]

_LABELS = types.uint16[::1]
_VALUES = types.float32[::1]
#: ``update(labels, values, meas_labels, meas_probs, params) -> counted``: one top-k measurement into one voxel.
UPDATE_SIG = types.boolean(_LABELS, _VALUES, _LABELS, _VALUES, types.float64[::1])
#: ``finish(labels, values, n_counted, params)``: once per voxel and frame, after its measurements.
FINISH_SIG = types.void(_LABELS, _VALUES, types.int64, types.float64[::1])


@nb.njit(cache=True, inline="always")
def new_scratch() -> tuple[np.ndarray, np.ndarray]:
    """Work arrays for :func:`fuse_measurement` (allocate once per thread, reuse for every call)."""
    return np.empty((3, SCRATCH), np.int64), np.empty((3, SCRATCH), np.float64)


@nb.njit(cache=True, inline="always")
def fuse_measurement(generic: bool, code: int, update, labels: np.ndarray, values: np.ndarray,
                     meas_labels: np.ndarray, meas_probs: np.ndarray, params: np.ndarray, si: np.ndarray,
                     sf: np.ndarray) -> bool:
    """Fuse one top-k measurement into one voxel's state in place; True if it counted (``finish_voxel``'s n).

    ``generic`` is ``code == GENERIC``, which a map kernel tests once, outside its loop, and passes as a constant
    (``if code == GENERIC: loop(True) else: loop(False)`` with an inlined loop): the built-in rules' loops then
    hold no call through a function value, which would keep the compiler from optimising them."""
    if generic:
        return update(labels, values, meas_labels, meas_probs, params)
    if code == TOPK_CODE:
        fuse_sets(labels, values, meas_labels, meas_probs, params[P_LAM], params[P_MAX_CONFIDENCE], labels, values,
                  si, sf)
        return True
    if code == MAX_CODE:
        return max_fuse(labels, values, meas_labels, meas_probs, params)
    if code in (BAYES_CODE, BAYES_PRIOR_CODE):
        return bayes_add(values, meas_labels, meas_probs)
    if code == VOTE_CODE:
        return vote_add(values, meas_labels)
    return False


@nb.njit(cache=True, inline="always")
def finish_voxel(generic: bool, code: int, finish, labels: np.ndarray, values: np.ndarray, n: int,
                 params: np.ndarray) -> None:
    """After a frame's ``n`` counted measurements of a voxel (n > 0): divide by the prior, normalise, clamp."""
    if n <= 0:
        return
    if generic:
        finish(labels, values, n, params)
        return
    if code in (TOPK_CODE, MAX_CODE):
        return
    if code == VOTE_CODE:
        normalise_votes(values, params[P_VOTE_CAP])
    elif code in (BAYES_CODE, BAYES_PRIOR_CODE):
        if code == BAYES_PRIOR_CODE:
            subtract_prior(values, params[P_PRIOR:], np.float64(n))
        normalise_logodds(values, params[P_CLAMP])


@nb.njit(cache=True, inline="always")
def merge_voxel(code: int, layout: int, update, labels: np.ndarray, values: np.ndarray, child_labels: np.ndarray,
                child_values: np.ndarray, params: np.ndarray, si: np.ndarray, sf: np.ndarray) -> None:
    """Fold a child's state into its parent's (inner nodes): a set is fused as a measurement (Algorithm 1 for
    ``topk``); log-odds and counts add up, then normalise (the children's evidence multiplied / pooled)."""
    if layout == LAYOUT_SET:
        fuse_measurement(code == GENERIC, code, update, labels, values, child_labels, child_values, params, si, sf)
        return
    for c in range(values.shape[0]):
        values[c] += child_values[c]
    if layout == LAYOUT_COUNTS:
        normalise_votes(values, params[P_VOTE_CAP])
    else:
        normalise_logodds(values, params[P_CLAMP])
