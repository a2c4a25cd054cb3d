"""A bounded, dense block of a map's space: unknown / free / occupied per voxel and the class of occupied voxels.

Every robot product (navigation grid, distance field) starts here, from any map kind: the OctoMap gives occupied
and free leaves; a voxel grid its occupied voxels and, when it kept free space, its occupancy OctoMap's free
leaves; a point map its points voxelised at its filter size (no free space: unknown stays unknown).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from semmap.errors import ConfigError
from semmap.keys import TREE_MAX_VAL, coords_to_keys, unpack_keys
from semmap.limits import check_memory
from semmap.maps.base import SemanticMap
from semmap.types import EMPTY_LABEL, LabelSet

UNKNOWN, FREE, OCCUPIED = np.int8(-1), np.int8(0), np.int8(1)
#: Bytes per voxel of a volume and the products made from it (state, class, distance, nearest site).
BYTES_PER_PRODUCT_VOXEL = 16


@dataclass(frozen=True)
class OccupancyVolume:
    """Voxel ``(i, j, k)`` has its centre at ``origin + (i, j, k) * resolution`` (world frame, metres)."""

    state: np.ndarray  # (nx, ny, nz) int8: UNKNOWN, FREE or OCCUPIED
    labels: np.ndarray  # (nx, ny, nz) uint16 top class of occupied voxels, EMPTY_LABEL elsewhere
    origin: np.ndarray  # (3,) float64 centre of voxel (0, 0, 0)
    resolution: float
    label_set: LabelSet | None = None

    @property
    def shape(self) -> tuple[int, int, int]:
        return tuple(int(n) for n in self.state.shape)  # type: ignore[return-value]

    def index_of(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) int64 voxel indices of world points (may fall outside the volume)."""
        return np.floor((np.asarray(points, np.float64) - self.origin) / self.resolution + 0.5).astype(np.int64)

    def counts(self) -> dict[str, int]:
        return {"unknown": int((self.state == UNKNOWN).sum()), "free": int((self.state == FREE).sum()),
                "occupied": int((self.state == OCCUPIED).sum())}


def map_keys(m: SemanticMap) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Occupied keys (N, 3), their top classes (N,) and free keys (F, 3) of any map kind."""
    if hasattr(m, "cells") and hasattr(m, "is_occupied"):  # the OctoMap (also a voxel grid's free space)
        v = m.voxels()
        c = m.cells()
        free = unpack_keys(c.packed[~m.is_occupied(c.logodds)])
        return v.keys, v.labels[:, 0].astype(np.uint16), free
    geometry = getattr(m, "geometry", None)
    if hasattr(m, "voxels"):  # the voxel grid
        v = m.voxels()
        free = map_keys(geometry)[2] if geometry is not None else np.zeros((0, 3), np.int64)
        return v.keys, v.labels.astype(np.uint16), free
    cloud = m.cloud()  # the point map: its points voxelised at its filter size
    keys = coords_to_keys(cloud.centers, cloud.resolution)
    return keys, cloud.labels.astype(np.uint16), np.zeros((0, 3), np.int64)


def _bounds_keys(bounds: tuple[np.ndarray, np.ndarray] | None, resolution: float, occ: np.ndarray,
                 free: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    if bounds is not None:
        lo, hi = (np.asarray(b, np.float64).reshape(3) for b in bounds)
        if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi)) and np.all(hi > lo)):
            raise ConfigError(f"the region must be finite with max > min on every axis, got {lo} .. {hi}")
        return coords_to_keys(lo[None], resolution)[0], coords_to_keys(hi[None], resolution)[0]
    both = np.concatenate([occ, free])
    if len(both) == 0:
        raise ConfigError("the map holds no occupied or free voxel: nothing to export")
    return both.min(axis=0), both.max(axis=0)


def occupancy_volume(m: SemanticMap, bounds: tuple[np.ndarray, np.ndarray] | None = None,
                     *, margin: int = 0) -> OccupancyVolume:
    """The dense volume of ``m`` over ``bounds`` ((min xyz, max xyz) in metres; default: everything the map
    knows), widened by ``margin`` voxels of unknown space on each side; refused beyond the memory budget."""
    keys = map_keys(m)
    res = float(m.resolution)
    lo, hi = _bounds_keys(bounds, res, keys[0], keys[2])
    return volume_of_keys(keys, res, lo - margin, hi + margin, getattr(m, "label_set", None),
                          option="--region: " if bounds is not None else "")


def volume_of_keys(keys: tuple[np.ndarray, np.ndarray, np.ndarray], res: float, lo: np.ndarray, hi: np.ndarray,
                   label_set: LabelSet | None, *, option: str = "") -> OccupancyVolume:
    """The dense volume of :func:`map_keys`' (occupied, classes, free) over the key box ``lo``..``hi``
    (inclusive); refused beyond the memory budget (the message starts with ``option``, the one that asked)."""
    occ, labels, free = keys
    shape = tuple(int(n) for n in hi - lo + 1)
    check_memory(f"{option}a product volume of {shape[0]}x{shape[1]}x{shape[2]} voxels at {res} m",
                 float(np.prod(shape, dtype=np.float64)) * BYTES_PER_PRODUCT_VOXEL)
    state = np.full(shape, UNKNOWN, np.int8)
    cls = np.full(shape, EMPTY_LABEL, np.uint16)
    for k, value in ((free, FREE), (occ, OCCUPIED)):
        idx = k - lo
        inside = np.all((idx >= 0) & (idx < np.array(shape)), axis=1)
        i = idx[inside]
        state[i[:, 0], i[:, 1], i[:, 2]] = value
        if value == OCCUPIED:
            cls[i[:, 0], i[:, 1], i[:, 2]] = labels[inside]
    origin = (lo.astype(np.float64) - TREE_MAX_VAL + 0.5) * res
    return OccupancyVolume(state, cls, origin, res, label_set)
