"""OctoMap voxel keys as numpy functions, shared by maps, the simulator's ground truth and evaluation.

``key = floor(double(float32(coord)) * (1 / resolution)) + 32768`` per axis (16 bits), packed into one int64
as ``x | y << 16 | z << 32``.  The numba kernels that must agree with OctoMap bit for bit are in
``maps/_keys.py``; these are their vectorised counterparts for whole arrays.
"""

from __future__ import annotations

import numpy as np

TREE_DEPTH = 16
TREE_MAX_VAL = 32768
KEY_LIMIT = 2 * TREE_MAX_VAL  # keys are valid in [0, KEY_LIMIT)


def coords_to_keys(points: np.ndarray, resolution: float) -> np.ndarray:
    """OctoMap keys (N, 3) int64 of (N, 3) points taken as float32 (unchecked)."""
    p = np.asarray(points, np.float32).astype(np.float64)
    return np.floor(p * (1.0 / resolution)).astype(np.int64) + TREE_MAX_VAL


def keys_to_coords(keys: np.ndarray, resolution: float) -> np.ndarray:
    """Cell centres (N, 3) float64 of (N, 3) keys."""
    return (np.asarray(keys, np.float64) - TREE_MAX_VAL + 0.5) * resolution


def pack_keys(keys: np.ndarray) -> np.ndarray:
    """(..., 3) keys as int64 ``x | y << 16 | z << 32``."""
    k = np.asarray(keys).astype(np.int64)
    return k[..., 0] | (k[..., 1] << 16) | (k[..., 2] << 32)


def unpack_keys(packed: np.ndarray) -> np.ndarray:
    """(N, 3) int64 keys of packed keys."""
    p = np.asarray(packed, np.int64)
    return np.stack([p & 0xFFFF, (p >> 16) & 0xFFFF, (p >> 32) & 0xFFFF], axis=-1)


def index_in(sorted_packed: np.ndarray, packed: np.ndarray) -> np.ndarray:
    """Position of each of the packed keys ``packed`` in ``sorted_packed`` (ascending), -1 where absent."""
    packed = np.asarray(packed, np.int64)
    if len(sorted_packed) == 0:
        return np.full(len(packed), -1, np.int64)
    pos = np.clip(np.searchsorted(sorted_packed, packed), 0, len(sorted_packed) - 1)
    return np.where(sorted_packed[pos] == packed, pos, -1)
