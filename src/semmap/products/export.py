"""``semmap export``: robot products written from a finished map into a staged output folder.

``grid``: ``map.pgm``/``map.yaml`` (trinary) and ``costmap.png``/``costmap.yaml``/``costmap.npy`` (scale) for ROS
map_server / nav2, and ``grid.json``. ``esdf``: ``esdf.npz`` (distance, observed, origin, resolution), a slice
picture ``esdf_slice.png`` and ``esdf.json``. ``mesh``: the TSDF's semantic mesh ``mesh.ply`` and
``mesh.json``. Each folder is written whole or not at all, never over the map.
"""

from __future__ import annotations

import io
import json
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from semmap.errors import ConfigError, FormatError, OutputError
from semmap.files.atomic import write_bytes_atomic, write_text_atomic
from semmap.files.outputs import OutputKind, check_outputs
from semmap.io.map_files import MAP_FILES, load_map, native_file
from semmap.io.staged_run import StagedRun
from semmap.maps.base import SemanticMap
from semmap.maps.registry import MapKind
from semmap.products.esdf import Esdf, esdf_of
from semmap.products.map_server import write_costmap, write_map
from semmap.products.navgrid import GridOptions, NavigationGrid, navigation_grid
from semmap.products.occupancy import occupancy_volume
from semmap.types import EMPTY_LABEL

SUMMARIES = ("grid.json", "esdf.json", "mesh.json")


def load_product_map(path: Path) -> tuple[SemanticMap, Path]:
    """A map from a ``.semmap`` file or a run folder (its native map files, the OctoMap first)."""
    path = Path(path)
    if path.is_dir():
        names = [n for kind in MapKind for n in MAP_FILES.get(kind, ()) if n.endswith(".semmap")]
        found = next((path / n for n in names if (path / n).is_file()), None)
        if found is None:
            raise FormatError(f"{path}: folder has none of {', '.join(names)} (map a sequence first with semmap run)")
        path = found
    elif path.suffix in (".ot", ".bt", ".ply"):
        raise FormatError(f"{path}: export reads semmap's lossless maps; give the .semmap file beside it (or the "
                          f"run folder)")
    return load_map(path), path


def _staged(out: Path, map_path: Path, write: Callable[[Path], dict]) -> dict:
    check_outputs([("--out", out, OutputKind.FOLDER)], [("MAP", map_path)])
    if out.is_dir() and any(out.iterdir()) and not any((out / s).is_file() for s in SUMMARIES):
        raise OutputError(f"--out {out}: holds other files (not an export of semmap); choose a new or empty folder "
                          f"(nothing was written)")
    staged = StagedRun(out)
    stage = staged.open()
    try:
        summary = write(stage)
        staged.commit()
    except BaseException:
        staged.abandon(keep_checkpoint=False)
        raise
    return summary


def _bounds(region: tuple[float, ...] | None) -> tuple[np.ndarray, np.ndarray] | None:
    return None if region is None else (np.array(region[:3]), np.array(region[3:]))


def grid_summary(g: NavigationGrid, map_path: Path, ms: float) -> dict:
    occ = g.occupancy
    return {"map": str(map_path), "resolution": g.resolution, "origin": [float(v) for v in g.origin],
            "size_cells": [int(n) for n in occ.shape], "floor_z": round(g.floor_z, 4),
            "band_z": [round(v, 4) for v in g.band], "cells": {"occupied": int((occ == 100).sum()),
                                                             "free": int((occ == 0).sum()),
                                                             "unknown": int((occ < 0).sum())},
            "class_cells": g.classes, "ms": round(ms, 1)}


def export_grid(map_path: Path, out: Path, options: GridOptions,
                region: tuple[float, ...] | None = None) -> dict:
    """Write the navigation grid and costmap of the map at ``map_path`` into the folder ``out``."""
    m, found = load_product_map(map_path)

    def write(stage: Path) -> dict:
        t = time.perf_counter()
        g = navigation_grid(occupancy_volume(m, _bounds(region)), options)
        ms = (time.perf_counter() - t) * 1e3
        write_map(stage, "map", g.occupancy, g.resolution, g.origin)
        write_costmap(stage, "costmap", g.cost, g.resolution, g.origin)
        summary = grid_summary(g, found, ms)
        write_text_atomic(stage / "grid.json", json.dumps(summary, indent=2) + "\n")
        return summary

    return _staged(Path(out), Path(map_path), write)


def slice_picture(e: Esdf, z: float | None) -> tuple[bytes, float]:
    """PNG of the horizontal slice of the field at height ``z`` (default: the middle of the region)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    k = e.distance.shape[2] // 2 if z is None else int(np.clip(round((z - e.origin[2]) / e.resolution), 0,
                                                                e.distance.shape[2] - 1))
    zk = float(e.origin[2] + k * e.resolution)
    d = np.where(np.isfinite(e.distance[:, :, k]), e.distance[:, :, k], np.nan).T
    ext = [e.origin[0] - e.resolution / 2, e.origin[0] + (d.shape[1] - 0.5) * e.resolution,
           e.origin[1] - e.resolution / 2, e.origin[1] + (d.shape[0] - 0.5) * e.resolution]
    fig, ax = plt.subplots(figsize=(6, 5))
    lim = float(np.nanmax(np.abs(d))) if np.isfinite(d).any() else 1.0
    im = ax.imshow(d, origin="lower", extent=ext, cmap="RdBu", vmin=-lim, vmax=lim)
    fig.colorbar(im, ax=ax, label="signed distance (m)")
    ax.set(xlabel="x (m)", ylabel="y (m)", title=f"ESDF slice at z = {zk:.2f} m")
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100, bbox_inches="tight")
    plt.close(fig)
    return buf.getvalue(), zk


def export_esdf(map_path: Path, out: Path, region: tuple[float, ...] | None = None,
                slice_z: float | None = None) -> dict:
    """Write the signed distance field of the map at ``map_path`` (and a slice picture) into the folder ``out``."""
    m, found = load_product_map(map_path)

    def write(stage: Path) -> dict:
        t = time.perf_counter()
        e = esdf_of(occupancy_volume(m, _bounds(region)))
        ms = (time.perf_counter() - t) * 1e3
        buf = io.BytesIO()
        np.savez_compressed(buf, distance=e.distance, observed=e.observed, origin=e.origin,
                            resolution=np.float64(e.resolution))
        write_bytes_atomic(stage / "esdf.npz", buf.getvalue())
        png, zk = slice_picture(e, slice_z)
        write_bytes_atomic(stage / "esdf_slice.png", png)
        fin = e.distance[np.isfinite(e.distance)]
        summary = {"map": str(found), "resolution": e.resolution, "origin": [float(v) for v in e.origin],
                   "size_voxels": [int(n) for n in e.distance.shape], "slice_z": round(zk, 4),
                   "max_distance_m": round(float(fin.max()), 4) if fin.size else None,
                   "observed_share": round(float(e.observed.mean()), 4), "ms": round(ms, 1)}
        write_text_atomic(stage / "esdf.json", json.dumps(summary, indent=2) + "\n")
        return summary

    return _staged(Path(out), Path(map_path), write)


def load_esdf(path: Path) -> Esdf:
    """An :class:`Esdf` from ``esdf.npz`` (or the export folder holding it)."""
    path = Path(path)
    if path.is_dir():
        path = path / "esdf.npz"
    try:
        with np.load(path, allow_pickle=False) as z:
            return Esdf(z["distance"], z["observed"], z["origin"], float(z["resolution"]))
    except (OSError, ValueError, KeyError) as exc:
        raise FormatError(f"{path}: not an esdf.npz written by semmap export esdf ({exc})") from None


def _tsdf_and_labels(path: Path) -> tuple[SemanticMap, SemanticMap | None, Path]:
    """The TSDF of a run folder (or a ``tsdf.semmap``) and the semantic map beside it that labels the mesh."""
    tsdf_file = native_file(MapKind.TSDF)
    hint = "map the sequence with semmap run --maps octomap,tsdf"
    path = Path(path)
    source = None
    if path.is_dir():
        if not (path / tsdf_file).is_file():
            raise FormatError(f"{path}: folder has no {tsdf_file} ({hint})")
        others = [native_file(k) for k in MapKind if k != MapKind.TSDF]
        found = next((path / n for n in others if (path / n).is_file()), None)
        source = None if found is None else load_map(found)
        path = path / tsdf_file
    tsdf = load_map(path)
    if tsdf.kind != MapKind.TSDF:
        raise FormatError(f"{path}: a {tsdf.kind.value} map holds no TSDF ({hint})")
    return tsdf, source, path


def export_mesh(map_path: Path, out: Path, *, min_weight: int = 1) -> dict:
    """Write the semantic mesh of the TSDF at ``map_path`` (a run folder or ``tsdf.semmap``) into ``out``."""
    from semmap.io.mesh_ply import write_mesh_ply
    from semmap.maps.mesh import semantic_mesh

    if not 1 <= int(min_weight) <= 10_000:
        raise ConfigError(f"--min-weight must be 1..10000, got {min_weight}")
    tsdf, source, found = _tsdf_and_labels(map_path)

    def write(stage: Path) -> dict:
        mesh = semantic_mesh(tsdf, source, min_weight=int(min_weight))
        size = write_mesh_ply(stage / "mesh.ply", mesh)
        classified = mesh.labels != EMPTY_LABEL
        summary = {"map": str(found), "labels_from": (source or tsdf).kind.value, "vertices": len(mesh),
                   "faces": len(mesh.faces), "bytes": size, "resolution": mesh.resolution,
                   "classified_share": round(float(classified.mean()) if len(mesh) else 0.0, 4),
                   "own_voxel_share": round(float(mesh.own_voxel.mean()) if len(mesh) else 0.0, 4),
                   "ms": round(mesh.ms, 1)}
        write_text_atomic(stage / "mesh.json", json.dumps(summary, indent=2) + "\n")
        return summary

    return _staged(Path(out), Path(map_path), write)
