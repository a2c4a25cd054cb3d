"""Numba kernel of ``semmap merge``: one map's class states folded into another's, voxel by voxel, by the rule."""

from __future__ import annotations

import numba as nb
import numpy as np

from semmap.fusion.dispatch import merge_voxel, new_scratch


@nb.njit(cache=True)
def merge_states(labels: np.ndarray, values: np.ndarray, other_labels: np.ndarray, other_values: np.ndarray,
                 code: int, layout: int, update, params: np.ndarray) -> None:
    """Fold row ``i`` of (``other_labels``, ``other_values``) into row ``i`` of (``labels``, ``values``) in place,
    as the fusion dispatcher folds a child into its parent (a set fused as a measurement; log-odds and counts
    added, then normalised)."""
    si, sf = new_scratch()
    for i in range(values.shape[0]):
        merge_voxel(code, layout, update, labels[i], values[i], other_labels[i], other_values[i], params, si, sf)
