"""The semantic voxel grid of *semantic-voxel-grid-mcl*: sparse voxels with a full K-class distribution each.

Every pixel that falls in a voxel updates its K log-odds (``bayes``, eqs. 2-5, by default; any rule of
``fusion/`` works), colour and hit count (:class:`~semmap.maps.semantic_grid.SemanticGrid`).  A voxel is occupied
once hit; with ``free_space`` the map also ray-casts each frame into an occupancy-only semantic OctoMap (the
octree's own insertion, OctoMap-exact) and a voxel counts as occupied only where that OctoMap says so, which
removes voxels that later rays pass through (depth noise, moved objects).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from semmap.fusion.rules import FusionParams, FusionRule
from semmap.keys import unpack_keys
from semmap.maps.base import MapState
from semmap.maps.registry import MapKind
from semmap.maps.semantic_grid import GridArrays, OnSemanticGrid, SemanticGrid
from semmap.maps.semantic_octomap import OCCUPIED, OccupancyParams, SemanticOctoMap
from semmap.types import LabelSet, MapCloud, Observation

#: Colour of voxels never coloured (frames without colour).
UNCOLOURED = 128


@dataclass(frozen=True)
class GridVoxels:
    """Occupied voxels as flat arrays: keys, centres, colour, hits, top class, its probability, entropy."""

    keys: np.ndarray  # (M, 3) int64 OctoMap keys
    centers: np.ndarray  # (M, 3) float64
    colors: np.ndarray  # (M, 3) uint8
    hits: np.ndarray  # (M,) uint16
    labels: np.ndarray  # (M,) uint16, EMPTY_LABEL where no class evidence
    confidence: np.ndarray  # (M,) float32
    entropy: np.ndarray  # (M,) float32 nats

    def __len__(self) -> int:
        return int(self.keys.shape[0])


class SemanticVoxelGrid(OnSemanticGrid):
    """Sparse voxel grid with K-class fusion (module docstring); a :class:`~semmap.maps.base.SemanticMap`."""

    kind = MapKind.VOXELGRID
    needs_normals = False

    def __init__(self, resolution: float = 0.05, *, label_set: LabelSet | None = None,
                 fusion: FusionParams | None = None, dtype: str = "float32", free_space: bool = False,
                 occupancy: OccupancyParams | None = None, max_range: float = -1.0, decay: float = 0.0) -> None:
        self.grid = SemanticGrid(resolution, label_set=label_set, fusion=fusion or FusionParams(FusionRule.BAYES),
                                 dtype=dtype)
        self.occupancy = occupancy or OccupancyParams()
        self.max_range = float(max_range)
        self.geometry = (SemanticOctoMap(resolution, occupancy=self.occupancy, max_range=max_range, decay=decay)
                         if free_space else None)

    @property
    def free_space(self) -> bool:
        return self.geometry is not None

    # ------------------------------------------------------------------ the map interface
    def integrate(self, obs: Observation) -> dict[str, float]:
        """Fuse every point of the frame; with free space, also ray-cast it into the occupancy OctoMap (the
        clear-only points of dynamic classes too: they clear its free space, and are never voxels)."""
        ms = self.grid.integrate_points(obs.points_world, colors=obs.colors, semantics=obs.semantics)
        if self.geometry is not None:
            ms["free_space"] = sum(self.geometry.insert_points(obs.points_world, obs.origin,
                                                               clear=obs.clear_points).ms.values())
        return ms

    def _occupied(self, a: GridArrays) -> np.ndarray:
        if self.geometry is None:
            return a.logodds >= 0.0  # hit at least once
        return self.geometry.state_at(self.grid.centers(a)) == OCCUPIED

    def voxels(self, *, occupied_only: bool = True) -> GridVoxels:
        """Voxels (occupied ones by default) sorted by key, with their top class, confidence and entropy."""
        a = self.grid.arrays()
        labels, conf, ent = self.grid.summary(a)
        sel = self._occupied(a) if occupied_only else np.ones(a.packed.shape[0], bool)
        keys = unpack_keys(a.packed[sel])
        colors = np.where(a.rgb_count[sel, None] > 0, a.rgb[sel], np.uint8(UNCOLOURED)).astype(np.uint8)
        return GridVoxels(keys, self.grid.centers(a)[sel], colors, a.hits[sel], labels[sel], conf[sel], ent[sel])

    def cloud(self) -> MapCloud:
        v = self.voxels()
        return MapCloud(v.centers, v.colors, v.labels, v.confidence, self.resolution)

    def class_at(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Most probable class and its probability at each (N, 3) world point: the occupied voxel holding it, as
        :meth:`cloud` reports it; EMPTY_LABEL and 0 where no occupied voxel holds the point."""
        return self.grid.class_at(points, self._occupied)

    def class_probs(self) -> np.ndarray:
        """(M, K) class distribution of each occupied voxel, in :meth:`cloud` order."""
        a = self.grid.arrays()
        sel = self._occupied(a)
        return self.grid.class_probs(a.select(sel))

    def points_per_view(self) -> np.ndarray:
        """(M,) measurements each occupied voxel's distribution sums per view, in :meth:`cloud` order
        (:meth:`SemanticGrid.points_per_view`)."""
        a = self.grid.arrays()
        return self.grid.points_per_view(a.select(self._occupied(a)))

    def class_probs_per_view(self) -> np.ndarray:
        """(M, K) distributions weighing each view once (what the CRF reads), in :meth:`cloud` order."""
        a = self.grid.arrays()
        return self.grid.class_probs_per_view(a.select(self._occupied(a)))

    def set_class_probs(self, probs: np.ndarray, *, where: np.ndarray | None = None) -> None:
        """Replace the distributions of the occupied voxels (:meth:`cloud` order; only rows ``where`` is True),
        e.g. by a CRF's posterior."""
        a = self.grid.arrays()
        packed = a.packed[self._occupied(a)]
        sel = np.ones(len(packed), bool) if where is None else np.asarray(where, bool)
        self.grid.set_class_probs(packed[sel], np.asarray(probs)[sel])

    def state(self) -> MapState:
        """The checkpoint state: the grid's, and the free-space OctoMap's under ``geometry/``."""
        geometry = {} if self.geometry is None else {f"geometry/{k}": v for k, v in self.geometry.state().items()}
        return {**self.grid.state(), **geometry}

    def restore(self, state: MapState) -> None:
        """Continue from :meth:`state` of a voxel grid built with the same parameters."""
        self.grid.restore({k: v for k, v in state.items() if not k.startswith("geometry/")})
        if self.geometry is not None:
            self.geometry.restore({k.removeprefix("geometry/"): v for k, v in state.items()
                                   if k.startswith("geometry/")})

    def describe(self) -> dict:
        a = self.grid.arrays()
        occupied = int(self._occupied(a).sum())
        mem = self.memory_bytes
        return {"voxels": int(a.packed.shape[0]), "occupied_voxels": occupied,
                "free_voxels": None if self.geometry is None else self.geometry.num_free,
                "fusion": self.fusion.name, "state_dtype": self.grid.dtype, "free_space": self.free_space,
                "bytes_in_memory": mem, "bytes_per_voxel_in_memory": round(mem / max(a.packed.shape[0], 1), 2)}

    @property
    def memory_bytes(self) -> int:
        return self.grid.memory_bytes + (0 if self.geometry is None else self.geometry.memory_bytes)

    def __repr__(self) -> str:
        return (f"SemanticVoxelGrid(resolution={self.resolution}, fusion={self.fusion.name}, "
                f"voxels={self.grid.num_voxels}, bytes={self.memory_bytes})")
