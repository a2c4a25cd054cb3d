"""The prior map as the particle filter reads it: dense lookup grids precomputed once per map.

A particle's score needs, for every observed point it places in the world, the nearest occupied voxel (for the
endpoint distance of the likelihood field) and that voxel's class distribution; the paper's cosine score needs
the top class of the voxel the point falls in.  All three become flat arrays over one box around the map
(``scipy.ndimage.distance_transform_edt`` gives the nearest occupied voxel of every cell), so that an update
is one array lookup per point and particle.  Free cells with clearance are kept for global initialisation.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy import ndimage

from semmap.errors import ConfigError, FormatError
from semmap.io.map_files import load_map, native_file
from semmap.limits import check_memory
from semmap.maps.registry import MapKind
from semmap.types import EMPTY_LABEL, LabelSet

#: Cells beyond this distance (m) from every occupied voxel get no nearest voxel (their points score as clutter).
DEFAULT_CUTOFF_M = 0.5
#: Empty space added around the map's known cells (m): points a little outside still find a nearest voxel.
GRID_MARGIN_M = 0.5
#: Global initialisation samples camera positions at least this far (m) from any occupied voxel.
DEFAULT_CLEARANCE_M = 0.2
#: Largest cell offset to a nearest voxel that the packed grid holds (int8 range); bounds the cutoff.
MAX_OFFSET_CELLS = 127
#: Largest lookup grid accepted (cells); bigger maps need a coarser resolution.
MAX_GRID_CELLS = 200_000_000
#: Bytes per lookup-grid cell while the prior is built (distance transform with indices, nearest voxel, packed
#: offsets, occupancy and free-space masks; measured about 5 GB for a 30-frame point map at 1 cm).
BYTES_PER_PRIOR_CELL = 96
#: A point map's points are pooled into cells this large (m) for the lookup grids: its filter cell (1 cm) would make
#: the grids 125 times larger than a 5 cm map's (1.9 GB for a 30-frame office), with no gain for a likelihood
#: field whose particles are scored at a few centimetres.
POINT_PRIOR_CELL_M = 0.05
#: Floor and ceiling heights are these percentiles of the occupied voxels' heights.
FLOOR_PERCENTILE, CEILING_PERCENTILE = 1.0, 99.0


@dataclass(frozen=True)
class PriorMap:
    """Flat lookup grids over a box around a prior semantic map (cell ``(ix, iy, iz)`` is flat index
    ``(ix * ny + iy) * nz + iz``; its lower corner is ``origin + resolution * (ix, iy, iz)``, world metres)."""

    resolution: float
    origin: np.ndarray  # (3,) float64 world position of the grid's lower corner
    shape: tuple[int, int, int]
    nearest: np.ndarray  # (cells,) int32 nearest occupied voxel within ``cutoff``, -1 = none
    nearest_packed: np.ndarray  # (cells,) int64 the same voxel | its cell offset (dx, dy, dz) + 128 << 32, 40, 48
    centers: np.ndarray  # (M, 3) float32 occupied voxel centres
    class_probs: np.ndarray | None  # (M, C) float32 class distribution per occupied voxel (None: no semantics)
    class_q: np.ndarray | None  # (M, >= C) uint8 the same x 255, rounded, rows padded to a cache-line fraction
    top_label: np.ndarray  # (cells,) uint16 most probable class of the occupied voxel in the cell, 0 = none
    free_clear: np.ndarray  # (cells,) bool: known free and at least ``clearance`` from every occupied voxel
    floor_z: float
    ceiling_z: float
    cutoff: float
    label_set: LabelSet | None

    @property
    def num_occupied(self) -> int:
        return int(self.centers.shape[0])

    @property
    def num_classes(self) -> int:
        return 0 if self.class_probs is None else int(self.class_probs.shape[1])

    def cell_index(self, points: np.ndarray) -> np.ndarray:
        """Flat cell index of each (N, 3) world point, -1 outside the grid."""
        ijk = np.floor((np.asarray(points, np.float64) - self.origin) / self.resolution).astype(np.int64)
        dims = np.asarray(self.shape)
        inside = ((ijk >= 0) & (ijk < dims)).all(axis=1)
        flat = (ijk[:, 0] * dims[1] + ijk[:, 1]) * dims[2] + ijk[:, 2]
        return np.where(inside, flat, -1)

    def cell_centers(self, flat: np.ndarray) -> np.ndarray:
        """World centres (N, 3) of flat cell indices."""
        _, ny, nz = self.shape
        flat = np.asarray(flat, np.int64)
        ijk = np.stack([flat // (ny * nz), (flat // nz) % ny, flat % nz], axis=1)
        return self.origin + (ijk + 0.5) * self.resolution

    def describe(self) -> dict:
        """Grid size and heights for the report."""
        return {"resolution": self.resolution, "grid_shape": list(self.shape), "occupied_voxels": self.num_occupied,
                "classes": self.num_classes, "floor_z": round(self.floor_z, 3), "ceiling_z": round(self.ceiling_z, 3),
                "free_cells_with_clearance": int(self.free_clear.sum()),
                "grid_bytes": int(sum(a.nbytes for a in (self.nearest, self.nearest_packed, self.top_label,
                                                         self.free_clear, self.centers))
                                  + (0 if self.class_q is None else self.class_q.nbytes))}


def dense_class_probs(labels: np.ndarray, probs: np.ndarray, num_classes: int) -> np.ndarray:
    """(M, C) distributions from top-k sets (M, k): the set's probabilities on its classes, the rest ("others")
    spread evenly over the real classes (1..C-1) outside the set; voxels without a set are uniform over them."""
    m, k = labels.shape
    out = np.zeros((m, num_classes), np.float32)
    valid = (labels != EMPTY_LABEL) & (labels < num_classes) & (labels > 0)
    rows = np.repeat(np.arange(m), k).reshape(m, k)
    np.add.at(out, (rows[valid], labels[valid].astype(np.int64)), probs[valid].astype(np.float32))
    real = num_classes - 1
    in_set = np.zeros((m, num_classes), bool)
    in_set[rows[valid], labels[valid].astype(np.int64)] = True
    outside = real - in_set[:, 1:].sum(axis=1)
    rest = np.clip(1.0 - out.sum(axis=1), 0.0, 1.0)
    share = np.where(outside > 0, rest / np.maximum(outside, 1), 0.0).astype(np.float32)
    fill = ~in_set
    fill[:, 0] = False
    out += fill * share[:, None]
    return out


def pack_nearest(nearest: np.ndarray, offset: np.ndarray) -> np.ndarray:
    """One int64 per cell: the nearest voxel's id (low 32 bits) and the offset (3, ...) in cells from the cell to
    that voxel's cell (+128, one byte each at bits 32, 40, 48); -1 where there is none.  The scoring kernel gets
    the endpoint distance from the cell record alone, without reading the voxel's centre."""
    out = nearest.astype(np.int64) & 0xFFFFFFFF
    for axis, shift in enumerate((32, 40, 48)):
        out |= (offset[axis].astype(np.int64) + 128) << shift
    out[nearest < 0] = -1
    return out


def _voxel_classes(occ_ijk: np.ndarray, shape: tuple[int, int, int], *, labels: np.ndarray | None,
                   probs: np.ndarray | None, dense_probs: np.ndarray | None, label_set: LabelSet | None
                   ) -> tuple[np.ndarray | None, np.ndarray]:
    """Each occupied voxel's class distribution (M, C) over the label set (None without classes) and the grid of
    top classes (0 where there is none), from dense distributions or top-k sets."""
    class_probs = None
    top = np.zeros(shape, np.uint16)
    if dense_probs is not None and label_set is not None:
        if dense_probs.shape[1] != len(label_set):
            raise ConfigError(f"class distributions have {dense_probs.shape[1]} classes, the label set "
                              f"{len(label_set)}")
        class_probs = np.ascontiguousarray(dense_probs, np.float32)
        class_probs[:, 0] = 0.0  # "unknown" is no class a point can be matched to
        class_probs /= np.maximum(class_probs.sum(axis=1, keepdims=True), 1e-12)
        no_evidence = class_probs.sum(axis=1) < 0.5
        class_probs[no_evidence, 1:] = 1.0 / (len(label_set) - 1)
        top[tuple(occ_ijk.T)] = np.where(no_evidence, 0, class_probs.argmax(axis=1))
    elif labels is not None and probs is not None and label_set is not None:
        labels = np.asarray(labels, np.uint16).reshape(len(occ_ijk), -1)
        probs = np.asarray(probs, np.float32).reshape(len(occ_ijk), -1)
        class_probs = dense_class_probs(labels, probs, len(label_set))
        first = labels[:, 0]
        top[tuple(occ_ijk.T)] = np.where((first != EMPTY_LABEL) & (first < len(label_set)), first, 0)
    return class_probs, top


def _quantised_rows(class_probs: np.ndarray) -> np.ndarray:
    """Class probabilities as bytes (x 255), rows padded to 32 (or a multiple of 64) bytes: one cache line per
    voxel for the scoring kernel."""
    width = 32 if class_probs.shape[1] <= 32 else -(-class_probs.shape[1] // 64) * 64
    class_q = np.zeros((len(class_probs), width), np.uint8)
    class_q[:, : class_probs.shape[1]] = np.round(class_probs * 255.0)
    return class_q


def build_prior(occupied_centers: np.ndarray, resolution: float, *, free_centers: np.ndarray | None = None,
                labels: np.ndarray | None = None, probs: np.ndarray | None = None,
                dense_probs: np.ndarray | None = None, label_set: LabelSet | None = None,
                cutoff: float = DEFAULT_CUTOFF_M, clearance: float = DEFAULT_CLEARANCE_M) -> PriorMap:
    """Lookup grids of a voxel map given its occupied voxel centres (M, 3), the class distributions of those
    voxels (top-k sets ``labels``/``probs`` (M, k), or ``dense_probs`` (M, C)) with their ``label_set``, and the
    known-free voxel centres.  Without free voxels, free space is taken to be the empty cells above a mapped
    surface (a floor seen below them), which keeps global initialisation off the outside of the walls."""
    occ = np.asarray(occupied_centers, np.float64).reshape(-1, 3)
    if len(occ) == 0:
        raise ConfigError("the prior map has no occupied voxels to localize against")
    if not (math.isfinite(resolution) and resolution > 0):
        raise ConfigError(f"map resolution must be positive, got {resolution}")
    free = np.zeros((0, 3)) if free_centers is None else np.asarray(free_centers, np.float64).reshape(-1, 3)
    res = float(resolution)
    known = np.concatenate([occ, free])
    margin = math.ceil(GRID_MARGIN_M / res)
    lo_cell = np.floor(known.min(axis=0) / res).astype(np.int64) - margin
    hi_cell = np.floor(known.max(axis=0) / res).astype(np.int64) + margin
    shape = tuple(int(v) for v in hi_cell - lo_cell + 1)
    cells = shape[0] * shape[1] * shape[2]
    cutoff = min(float(cutoff), MAX_OFFSET_CELLS * res)
    if cells > MAX_GRID_CELLS:
        raise ConfigError(f"the prior map spans {shape} cells of {res} m ({cells:,}); more than {MAX_GRID_CELLS:,} "
                          f"do not fit a lookup grid (map at a coarser resolution)")
    check_memory(f"the prior map's lookup grid of {'x'.join(map(str, shape))} cells of {res:g} m (a map at a coarser "
                 "resolution needs less)", cells * BYTES_PER_PRIOR_CELL)
    origin = lo_cell * res

    def ijk_of(points: np.ndarray) -> np.ndarray:
        return np.floor(points / res).astype(np.int64) - lo_cell

    occ_ijk = ijk_of(occ)
    # voxels numbered in the grid's own order, so that nearby cells read nearby rows (cache locality)
    order = np.argsort((occ_ijk[:, 0] * shape[1] + occ_ijk[:, 1]) * shape[2] + occ_ijk[:, 2], kind="stable")
    occ, occ_ijk = occ[order], occ_ijk[order]
    if labels is not None and probs is not None:
        labels = np.asarray(labels).reshape(len(order), -1)[order]
        probs = np.asarray(probs).reshape(len(order), -1)[order]
    if dense_probs is not None:
        dense_probs = np.asarray(dense_probs, np.float32).reshape(len(order), -1)[order]
    occ_grid = np.zeros(shape, bool)
    occ_grid[tuple(occ_ijk.T)] = True
    voxel_of = np.full(shape, -1, np.int32)
    voxel_of[tuple(occ_ijk.T)] = np.arange(len(occ), dtype=np.int32)
    # nearest occupied cell of every cell (distance in cells), and the voxel there
    dist, idx = ndimage.distance_transform_edt(~occ_grid, return_indices=True)
    nearest = voxel_of[idx[0], idx[1], idx[2]]
    nearest[dist * res > cutoff + 1e-9] = -1
    packed = pack_nearest(nearest, idx - np.indices(shape, dtype=np.int32))
    free_grid = np.zeros(shape, bool)
    if len(free):
        free_grid[tuple(ijk_of(free).T)] = True
    else:  # no free-space information: empty cells with a mapped surface somewhere below them
        free_grid = np.maximum.accumulate(occ_grid, axis=2) & ~occ_grid
    free_clear = free_grid & ~occ_grid & (dist * res >= clearance)

    class_probs, top = _voxel_classes(occ_ijk, shape, labels=labels, probs=probs, dense_probs=dense_probs,
                                      label_set=label_set)
    z = occ[:, 2]
    known_z = known[:, 2]  # the ceiling may be unmapped (cameras look down): the known space's top bounds it then
    class_q = None if class_probs is None else _quantised_rows(class_probs)
    return PriorMap(res, origin.astype(np.float64), shape, np.ascontiguousarray(nearest.reshape(-1), np.int32),
                    packed.reshape(-1),
                    np.ascontiguousarray(occ, np.float32), class_probs, class_q, top.reshape(-1),
                    free_clear.reshape(-1),
                    float(np.percentile(z, FLOOR_PERCENTILE)),
                    float(max(np.percentile(z, CEILING_PERCENTILE), np.percentile(known_z, CEILING_PERCENTILE))),
                    float(cutoff), label_set)


def prior_from_octomap(m, *, cutoff: float = DEFAULT_CUTOFF_M, clearance: float = DEFAULT_CLEARANCE_M) -> PriorMap:
    """Lookup grids of a :class:`~semmap.maps.semantic_octomap.SemanticOctoMap` (occupied voxels with their top-k
    sets, free voxels for initialisation)."""
    occ = m.voxels(occupied_only=True)
    cells = m.cells()
    free_packed = cells.packed[~m.is_occupied(cells.logodds)]
    from semmap.keys import keys_to_coords, unpack_keys

    free = keys_to_coords(unpack_keys(free_packed), m.resolution)
    return build_prior(occ.centers, m.resolution, free_centers=free, labels=occ.labels, probs=occ.probs,
                       label_set=m.label_set, cutoff=cutoff, clearance=clearance)


def prior_from_grid_map(m, *, cutoff: float = DEFAULT_CUTOFF_M, clearance: float = DEFAULT_CLEARANCE_M) -> PriorMap:
    """Lookup grids of a :class:`~semmap.maps.voxel_grid.SemanticVoxelGrid` (or point map): its occupied voxels
    with their full class distributions; free space from its occupancy OctoMap when it keeps one."""
    cloud = m.cloud()
    dense = m.class_probs() if m.label_set is not None else None
    centers, resolution = cloud.centers, float(m.resolution)
    if m.kind == MapKind.POINTS and resolution < POINT_PRIOR_CELL_M:
        centers, dense = pooled_cells(centers, dense, POINT_PRIOR_CELL_M)
        resolution = POINT_PRIOR_CELL_M
    free = None
    geometry = getattr(m, "geometry", None)
    if geometry is not None:
        cells = geometry.cells()
        from semmap.keys import keys_to_coords, unpack_keys

        free = keys_to_coords(unpack_keys(cells.packed[~geometry.is_occupied(cells.logodds)]), m.resolution)
    return build_prior(centers, resolution, free_centers=free, dense_probs=dense, label_set=m.label_set,
                       cutoff=cutoff, clearance=clearance)


def pooled_cells(points: np.ndarray, probs: np.ndarray | None, cell: float) -> tuple[np.ndarray, np.ndarray | None]:
    """The centres (M, 3) of the ``cell``-sized cells holding ``points`` (N, 3), and each cell's class distribution:
    the mean of its points' rows of ``probs`` (N, C), None without classes."""
    if not len(points):
        return np.zeros((0, 3)), probs
    ijk = np.floor(np.asarray(points, np.float64) / cell).astype(np.int64)
    cells, inverse, counts = np.unique(ijk, axis=0, return_inverse=True, return_counts=True)
    centers = (cells + 0.5) * cell
    if probs is None:
        return centers, None
    order = np.argsort(inverse.reshape(-1), kind="stable")
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    pooled = np.add.reduceat(np.asarray(probs, np.float64)[order], starts, axis=0)
    return centers, (pooled / counts[:, None]).astype(np.float32)


#: Map files of a run folder, in the order ``load_prior`` looks for them.
MAP_FILES = tuple(native_file(kind) for kind in MapKind)


def load_prior(path: str | Path, **kwargs) -> PriorMap:
    """Lookup grids of a map file written by semmap: the octree's ``map.semmap``, a voxel grid's
    ``voxelgrid.semmap`` (or a point map's), or a run folder holding one of them."""
    path = Path(path)
    if path.is_dir():
        found = next((path / name for name in MAP_FILES if (path / name).is_file()), None)
        if found is None:
            raise FormatError(f"{path}: folder has none of {', '.join(MAP_FILES)} (map a sequence first with "
                              f"semmap run)")
        path = found
    elif path.suffix in (".ot", ".bt", ".ply"):
        raise FormatError(f"{path}: localize needs a semmap map with its class evidence, one of "
                          f"{', '.join(MAP_FILES)} (or the run folder holding it); a {path.suffix} file has no "
                          f"class sets to localize against")
    m = load_map(path)
    try:
        return prior_from_octomap(m, **kwargs) if m.kind == MapKind.OCTOMAP else prior_from_grid_map(m, **kwargs)
    except ConfigError as exc:  # an empty or odd map: say which file
        raise ConfigError(f"{path}: {exc}") from None
