"""A truncated signed distance field beside the maps, for a surface mesh (``semmap run --maps ...,tsdf``).

Each frame's rays from the sensor origin to its world points update the voxels within ``truncation`` of each end
point with their projective distance along the ray (positive in front of the surface), averaged with integer
weights (the "simple" ray integrator of voxblox, Oleynikova et al. 2017); the voxels live in the same sharded hash
table and OctoMap keys as the other maps. Its colours and classes are a voxel grid's (the class is the base
class's): on its own it is a semantic map like the others, and :mod:`semmap.maps.mesh` labels its mesh from the
run's semantic map. :meth:`TsdfMap.mesh` is marching cubes over the voxels (``maps/_tsdf_kernels.py``).
"""

from __future__ import annotations

import time

import numpy as np

from semmap.errors import ConfigError
from semmap.fusion.rules import FusionParams
from semmap.maps import _tsdf_kernels as kern
from semmap.maps._hashtable import ShardedTable
from semmap.maps.base import MapState, check_state
from semmap.maps.registry import MapKind
from semmap.maps.voxel_grid import SemanticVoxelGrid
from semmap.types import LabelSet, Observation

#: Default truncation distance, in voxels (3-4 voxels is the usual choice of voxblox and nvblox).
DEFAULT_TRUNCATION_VOXELS = 4.0
#: Weights stop growing here, so that the field still follows a changed scene (voxblox's default).
MAX_WEIGHT = 10_000
#: Observations a voxel needs before marching cubes uses it.
DEFAULT_MIN_WEIGHT = 1
_STATE = ("tsdf_keys", "tsdf_sdf", "tsdf_weight", "tsdf_counts", "tsdf_capacity")


class TsdfMap(SemanticVoxelGrid):
    """TSDF at ``resolution`` with truncation ``truncation`` voxels, plus a voxel grid's colours and classes."""

    kind = MapKind.TSDF

    def __init__(self, resolution: float = 0.05, *, label_set: LabelSet | None = None,
                 fusion: FusionParams | None = None, dtype: str = "float32",
                 truncation: float = DEFAULT_TRUNCATION_VOXELS) -> None:
        super().__init__(resolution, label_set=label_set, fusion=fusion, dtype=dtype)
        if not (np.isfinite(truncation) and 1.0 <= truncation <= 64.0):
            raise ConfigError(f"--tsdf-truncation must be between 1 and 64 voxels, got {truncation}")
        self.truncation = float(truncation)
        self.table = ShardedTable()

    @property
    def truncation_m(self) -> float:
        return self.truncation * self.resolution

    # ------------------------------------------------------------------ the map interface
    def integrate(self, obs: Observation) -> dict[str, float]:
        """The voxel grid's colours and classes, then every ray's distances into the TSDF."""
        ms = super().integrate(obs)
        t0 = time.perf_counter()
        self.integrate_rays(obs.points_world, obs.origin)
        ms["field"] = (time.perf_counter() - t0) * 1e3
        return ms

    def integrate_rays(self, points: np.ndarray, origin: np.ndarray) -> None:
        """Fuse the rays from ``origin`` (3,) to each (N, 3) world point into the field: one ray to the mean of the
        points in each voxel, weighted by their number (voxblox's "merged" integrator; a voxel at 2 cm holds tens
        of a Kinect frame's pixels)."""
        o = np.asarray(origin, np.float64).reshape(3)
        if not np.isfinite(o).all():
            raise ConfigError("the sensor origin of an observation must be finite")
        pts, per_ray = merged_rays(points, self.resolution)
        steps = 3 * (int(np.ceil(2.0 * self.truncation)) + 3)
        slots, values = np.empty(steps, np.int64), np.empty(steps, np.float32)
        t, start = self.table, 0
        while start < len(pts):
            start = kern.integrate_rays(t.keys, t.logodds, t.attr, t.counts, t.shard_cap, t.fill_limit, pts, per_ray,
                                        o, 1.0 / self.resolution, self.truncation_m, MAX_WEIGHT, start, slots, values)
            if start < len(pts):
                t.grow(t.shard_cap + 1)
        t.settle()

    def field(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Every TSDF voxel in key order: packed keys (M,) int64, signed distance (M,) float32 metres, weight (M,)."""
        t = self.table
        used = t.used()
        order = np.argsort(t.keys[used], kind="stable")
        used = used[order]
        return t.keys[used], t.logodds[used], np.maximum(t.attr[used], 0)

    def load_field(self, packed: np.ndarray, sdf: np.ndarray, weight: np.ndarray) -> None:
        """Replace the field by :meth:`field`'s arrays (a file read back)."""
        self.table.load(packed, np.asarray(sdf, np.float32), np.asarray(weight, np.int32))

    def mesh(self, min_weight: int = DEFAULT_MIN_WEIGHT) -> tuple[np.ndarray, np.ndarray]:
        """Marching cubes at the zero crossing: vertices (V, 3) float32 world metres (one per cut voxel edge, in
        edge order) and triangles (F, 3) int32 in voxel key order, counter-clockwise seen from the free side."""
        t = self.table
        used = t.used()
        used = used[np.argsort(t.keys[used], kind="stable")]  # triangles in key order, whatever the table's layout
        tables = kern.case_tables()
        cases, ntri = kern.cube_cases(t.keys, t.logodds, t.attr, t.shard_cap, used, int(min_weight), tables)
        first = np.concatenate([[0], np.cumsum(ntri)[:-1]]).astype(np.int64)
        total = int(ntri.sum())
        edge_ids = np.empty(3 * total, np.int64)
        positions = np.empty((3 * total, 3), np.float64)
        kern.cube_triangles(t.keys, t.logodds, t.shard_cap, used, cases, first, tables, kern.EDGES,
                            self.resolution, edge_ids, positions)
        _, index, inverse = np.unique(edge_ids, return_index=True, return_inverse=True)
        return positions[index].astype(np.float32), inverse.reshape(-1, 3).astype(np.int32)

    def state(self) -> MapState:
        """The voxel grid's checkpoint state and the TSDF's hash table."""
        t = self.table
        return {**super().state(), "tsdf_keys": t.keys, "tsdf_sdf": t.logodds, "tsdf_weight": t.attr,
                "tsdf_counts": t.counts, "tsdf_capacity": np.int64(t.shard_cap)}

    def restore(self, state: MapState) -> None:
        """Continue from :meth:`state` of a TSDF built with the same parameters."""
        check_state(state, _STATE, "a TSDF")
        super().restore({k: v for k, v in state.items() if k not in _STATE})
        t = self.table
        t.keys, t.logodds = np.ascontiguousarray(state["tsdf_keys"]), np.ascontiguousarray(state["tsdf_sdf"])
        t.attr, t.counts = np.ascontiguousarray(state["tsdf_weight"]), np.ascontiguousarray(state["tsdf_counts"])
        t.shard_cap = int(state["tsdf_capacity"])

    def describe(self) -> dict:
        d = super().describe()
        voxels = int(self.table.counts.sum())
        d.update({"tsdf_voxels": voxels, "truncation_voxels": self.truncation, "bytes_in_memory": self.memory_bytes,
                  "bytes_per_voxel_in_memory": round(self.memory_bytes / max(voxels, 1), 2)})
        return d

    @property
    def memory_bytes(self) -> int:
        return super().memory_bytes + self.table.nbytes

    def __repr__(self) -> str:
        return (f"TsdfMap(resolution={self.resolution}, truncation={self.truncation} voxels, "
                f"voxels={int(self.table.counts.sum())}, bytes={self.memory_bytes})")


def merged_rays(points: np.ndarray, resolution: float) -> tuple[np.ndarray, np.ndarray]:
    """The mean (M, 3) float64 of the finite points in each voxel, in key order, and their number (M,) int32."""
    return kern.merge_points(np.ascontiguousarray(points, np.float64).reshape(-1, 3), 1.0 / resolution)


def compile_kernels() -> None:
    """Integrate one tiny scan and mesh it, so numba compiles (or loads) the TSDF's kernels now."""
    m = TsdfMap(0.05)
    rng = np.random.default_rng(0)
    pts = np.column_stack([np.full(200, 1.0), rng.uniform(-0.3, 0.3, (200, 2))])
    m.integrate_rays(pts, np.zeros(3))
    m.mesh()
