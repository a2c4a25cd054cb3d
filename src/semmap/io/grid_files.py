"""Lossless files of the hashed semantic maps (``voxelgrid.semmap``, ``points.semmap``, ``tsdf.semmap``).

A zip of numpy arrays (``numpy.savez_compressed``) and a JSON header: format, version, map kind, resolution,
state dtype, fusion rule and settings, label set (and, for a voxel grid with free space, its occupancy
OctoMap's cells; for the TSDF, its truncation and its voxels' keys, distances and weights).
``save_grid -> load_grid`` gives back a map whose arrays are bit-identical.
"""

from __future__ import annotations

import json
from dataclasses import fields
from pathlib import Path

import numpy as np

from semmap.errors import FormatError, SemmapError
from semmap.files.atomic import write_atomic
from semmap.fusion.rules import FusionParams
from semmap.limits import check_file_resolution
from semmap.maps.registry import MapKind
from semmap.maps.semantic_grid import GridArrays
from semmap.maps.semantic_octomap import CellArrays, OccupancyParams, SemanticOctoMap
from semmap.types import LabelSet

FORMAT = "semmap-grid"
VERSION = 1
_GRID_FIELDS = tuple(f.name for f in fields(GridArrays))


def save_grid(path: str | Path, m) -> int:
    """Write a :class:`~semmap.maps.voxel_grid.SemanticVoxelGrid` or
    :class:`~semmap.maps.point_map.SemanticPointMap` atomically; returns the file size in bytes."""
    g = m.grid
    f = g.fusion
    header = {
        "format": FORMAT, "version": VERSION, "kind": m.kind.value, "resolution": g.resolution, "dtype": g.dtype,
        "fusion": {"rule": f.name, "k": f.k, "lam": f.lam, "max_confidence": f.max_confidence,
                   "logodds_clamp": f.logodds_clamp, "vote_cap": f.vote_cap, "prior_smoothing": f.prior_smoothing,
                   "prior": None if f.prior is None else [float(v) for v in f.prior]},
        "label_set": None if g.label_set is None else g.label_set.to_dict(),
    }
    a = g.arrays()
    arrays = {name: getattr(a, name) for name in _GRID_FIELDS}
    if m.kind in (MapKind.VOXELGRID, MapKind.TSDF):
        header.update({"occupancy": vars(m.occupancy), "max_range": m.max_range, "free_space": m.free_space})
        if m.geometry is not None:
            cells = m.geometry.cells()
            arrays["geo_packed"], arrays["geo_logodds"] = cells.packed, cells.logodds
        if m.kind == MapKind.TSDF:
            header["truncation"] = m.truncation
            arrays["tsdf_packed"], arrays["tsdf_sdf"], arrays["tsdf_weight"] = m.field()
    else:
        header.update({"keyframes_only": m.keyframes_only, "frames_integrated": m.frames_integrated})
    arrays["header"] = np.frombuffer(json.dumps(header).encode("utf-8"), np.uint8)
    write_atomic(path, lambda fobj: np.savez_compressed(fobj, **arrays))
    return Path(path).stat().st_size


def read_header(path: str | Path) -> dict:
    """The JSON header of a grid file (what ``semmap info`` shows without loading every array)."""
    from semmap.files.safe import json_from_bytes, read_npz_members

    path = Path(path)
    header = json_from_bytes(path, read_npz_members(path, ["header"], what="semmap map")["header"].tobytes())
    if not isinstance(header, dict):
        raise FormatError(f"{path}: header must be a JSON object, got {type(header).__name__}")
    if header.get("format") != FORMAT:
        raise FormatError(f"{path}: not a semmap grid map (format {header.get('format')!r})")
    if header.get("version") != VERSION:
        raise FormatError(f"{path}: unsupported semmap grid version {header.get('version')!r} (this is {VERSION})")
    return header


def load_grid(path: str | Path):
    """Read a map written by :func:`save_grid` (a voxel grid or a point map, as its header says)."""
    from semmap.maps.point_map import SemanticPointMap
    from semmap.maps.voxel_grid import SemanticVoxelGrid

    path = Path(path)
    from semmap.files.safe import read_npz_members

    header = read_header(path)
    check_file_resolution(header.get("resolution"), path)
    arrays = read_npz_members(path, what="semmap map")
    arrays.pop("header", None)
    missing = set(_GRID_FIELDS) - set(arrays)
    if missing:
        raise FormatError(f"{path}: not a semmap grid map (missing {sorted(missing)})")
    try:
        fz = dict(header["fusion"])
        prior = fz.pop("prior")
        fusion = FusionParams(**fz, prior=None if prior is None else np.array(prior))
        label_set = None if header["label_set"] is None else LabelSet.from_dict(header["label_set"])
        kind = MapKind(header["kind"])
        resolution, dtype = float(header["resolution"]), str(header["dtype"])
        if kind == MapKind.TSDF:
            m = _tsdf_of(path, header, arrays, resolution, label_set, fusion, dtype)
        elif kind == MapKind.VOXELGRID:
            m = SemanticVoxelGrid(resolution, label_set=label_set, fusion=fusion, dtype=dtype,
                                  free_space=bool(header["free_space"]),
                                  occupancy=OccupancyParams(**header["occupancy"]),
                                  max_range=float(header["max_range"]))
        else:
            m = SemanticPointMap(resolution, label_set=label_set, fusion=fusion, dtype=dtype,
                                 keyframes_only=bool(header["keyframes_only"]))
            m.frames_integrated = int(header["frames_integrated"])
    except FormatError:
        raise
    except (KeyError, TypeError, ValueError, AttributeError, SemmapError) as exc:
        raise FormatError(f"{path}: malformed header ({exc})") from None
    grid = GridArrays(**{name: arrays[name] for name in _GRID_FIELDS})
    _check(path, grid, m)
    m.grid.load_arrays(grid)
    if kind != MapKind.POINTS and m.geometry is not None:
        if "geo_packed" not in arrays or "geo_logodds" not in arrays:
            raise FormatError(f"{path}: free-space map without its occupancy cells")
        n = arrays["geo_packed"].shape[0]
        if not np.isfinite(np.asarray(arrays["geo_logodds"], np.float64)).all():
            raise FormatError(f"{path}: occupancy cells with non-finite (NaN or infinite) log-odds")
        m.geometry = SemanticOctoMap.from_cells(
            resolution, CellArrays(arrays["geo_packed"], arrays["geo_logodds"], np.full(n, -1, np.int32),
                                   np.zeros((0, 3), np.uint8), np.zeros(0, np.uint16),
                                   np.zeros((0, 3), np.uint16), np.zeros((0, 3), np.float32)),
            occupancy=m.occupancy, max_range=m.max_range)
    return m


def _tsdf_of(path: Path, header: dict, arrays: dict, resolution: float, label_set, fusion, dtype: str):
    """An empty-grid TSDF with the file's field loaded (its keys unique and in range, distances finite)."""
    from semmap.maps.tsdf import TsdfMap

    m = TsdfMap(resolution, label_set=label_set, fusion=fusion, dtype=dtype, truncation=float(header["truncation"]))
    try:
        packed, sdf, weight = (np.asarray(arrays[n]) for n in ("tsdf_packed", "tsdf_sdf", "tsdf_weight"))
    except KeyError:
        raise FormatError(f"{path}: TSDF map without its field (tsdf_packed, tsdf_sdf, tsdf_weight)") from None
    n = packed.shape[0]
    if (packed.dtype != np.int64 or sdf.dtype != np.float32 or weight.dtype != np.int32 or packed.shape != (n,)
            or sdf.shape != (n,) or weight.shape != (n,)):
        raise FormatError(f"{path}: TSDF arrays must be (n,) int64 keys, float32 distances, int32 weights")
    if n and (packed.min() < 0 or packed.max() >= 1 << 48 or np.unique(packed).size != n
              or not np.isfinite(sdf).all() or weight.min() < 0):
        raise FormatError(f"{path}: invalid TSDF voxels (duplicate or out-of-range keys, non-finite distances)")
    m.load_field(packed, sdf, weight)
    return m


def _check(path: Path, a: GridArrays, m) -> None:
    """Shapes and dtypes as the map's settings say, unique in-range keys."""
    g = m.grid
    k_dense, s_pairs = g._widths()
    state = np.uint16 if g.dtype == "float16" else np.float32
    geo = 3 if g.keep_geometry else 0
    n = a.packed.shape[0]
    expected = {"packed": (np.int64, (n,)), "logodds": (np.float32, (n,)), "rgb": (np.uint8, (n, 3)),
                "rgb_count": (np.uint16, (n,)), "hits": (np.uint16, (n,)), "dense": (state, (n, k_dense)),
                "set_labels": (np.uint16, (n, s_pairs)), "set_probs": (state, (n, s_pairs)),
                "positions": (np.float32, (n, geo)), "normal_sums": (np.float32, (n, geo))}
    for name, (dtype, shape) in expected.items():
        arr = getattr(a, name)
        if arr.dtype != dtype or arr.shape != shape:
            raise FormatError(f"{path}: array {name!r} is {arr.dtype}{arr.shape}, expected {np.dtype(dtype)}{shape}")
    for name in ("logodds", "dense", "set_probs", "positions", "normal_sums"):
        arr = getattr(a, name)
        values = arr.view(np.float16) if arr.dtype == np.uint16 else arr  # (float16 state is stored as its bits)
        if values.size and not np.isfinite(values).all():
            what = "log-odds" if name == "logodds" else f"values in {name!r}"
            raise FormatError(f"{path}: {int((~np.isfinite(values)).sum()):,} non-finite (NaN or infinite) {what}")
    p = a.packed
    if p.size and (p.min() < 0 or p.max() >= 1 << 48 or np.unique(p).size != p.size):
        raise FormatError(f"{path}: invalid or duplicate voxel keys")
