"""``semmap export``: robot products written from a finished map into a staged output folder.

``grid``: ``map.pgm``/``map.yaml`` (trinary) and ``costmap.png``/``costmap.yaml``/``costmap.npy`` (scale)
for ROS map_server / nav2, and ``grid.json``. ``esdf``: ``esdf.npz`` (distance, observed, origin, resolution),
a slice picture ``esdf_slice.png`` and ``esdf.json``. ``mesh``: the TSDF's semantic mesh ``mesh.ply`` and
``mesh.json``. ``scene-graph``: ``scene_graph.json`` (spark-dsg, as Hydra's tools read it) and ``graph.json``
(counts and relations). ``semmap diff``: ``diff.json``, ``diff.ply``, ``diff.png``. Each folder is written whole
or not at all, never over its inputs.
"""

from __future__ import annotations

import io
import json
import logging
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from semmap.errors import ConfigError, FormatError, OutputError
from semmap.files.atomic import write_bytes_atomic, write_text_atomic
from semmap.files.outputs import OutputKind, check_outputs
from semmap.io.map_files import MAP_FILES, load_map, native_file
from semmap.io.staged_run import run_staged
from semmap.maps.base import SemanticMap
from semmap.maps.registry import MapKind
from semmap.products.esdf import Esdf, esdf_of
from semmap.products.map_server import write_costmap, write_map
from semmap.products.navgrid import GridOptions, NavigationGrid, navigation_grid
from semmap.products.occupancy import map_keys, occupancy_volume
from semmap.types import EMPTY_LABEL

LOG = logging.getLogger("semmap")

#: Each kind of export: the command that writes it, its summary file (first) and every file it writes. An export
#: replaces an earlier export of its own kind only: a folder holding anything else is refused.
PRODUCTS = {
    "grid": ("semmap export grid", ("grid.json", "map.pgm", "map.yaml", "costmap.png", "costmap.yaml",
                                    "costmap.npy")),
    "esdf": ("semmap export esdf", ("esdf.json", "esdf.npz", "esdf_slice.png")),
    "scene-graph": ("semmap export scene-graph", ("graph.json", "scene_graph.json")),
    "diff": ("semmap diff", ("diff.json", "diff.ply", "diff.png")),
    "mesh": ("semmap export mesh", ("mesh.json", "mesh.ply")),
}
SUMMARIES = tuple(files[0] for _, files in PRODUCTS.values())


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
        raise FormatError(f"{path}: a {path.suffix} file is not one of semmap's lossless maps (.semmap, with every "
                          f"voxel's class evidence); give the .semmap file beside it (or the run folder)")
    return load_map(path), path


def check_replaceable(out: Path, product: str) -> None:
    """``out`` is new, empty or an earlier export of the same kind (its summary file and none but its files);
    anything else, another kind of export included, would be lost by replacing the folder: one OutputError line."""
    if not out.is_dir() or not any(out.iterdir()):
        return
    command, files = PRODUCTS[product]
    present = sorted(p.name for p in out.iterdir())
    if (out / files[0]).is_file() and set(present) <= set(files):
        return
    other = next(((cmd, fs[0]) for kind, (cmd, fs) in PRODUCTS.items() if kind != product and (out / fs[0]).is_file()),
                 None)
    what = (f"holds the output of {other[0]} ({other[1]})" if other is not None
            else "holds other files (not an export of semmap)" if not (out / files[0]).is_file()
            else f"holds files {command} did not write ({', '.join(n for n in present if n not in files)})")
    raise OutputError(f"--out {out}: {what}, which {command} would replace; choose a new or empty folder (nothing was "
                      f"written)")


def _staged(out: Path, inputs: Path | list[tuple[str, Path]], write: Callable[[Path], dict], product: str) -> dict:
    named = [("MAP", inputs)] if isinstance(inputs, Path) else inputs
    check_outputs([("--out", out, OutputKind.FOLDER)], named)
    check_replaceable(out, product)
    return run_staged(out, write)


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
    if not len(map_keys(m)[2]):
        LOG.warning(f"{found}: a {m.kind.value} map keeps no free space, so the grid has no free cell (occupied and "
                    f"unknown only) and a planner finds no path in it; export an OctoMap (map.semmap) or a voxel grid "
                    f"mapped with --free-space for a grid to plan in")

    def write(stage: Path) -> dict:
        t = time.perf_counter()
        g = navigation_grid(occupancy_volume(m, _bounds(region)), options)
        ms = (time.perf_counter() - t) * 1e3
        write_map(stage, "map", g.occupancy, g.resolution, g.origin)
        write_costmap(stage, "costmap", g.cost, g.resolution, g.origin)
        summary = grid_summary(g, found, ms)
        write_text_atomic(stage / "grid.json", json.dumps(summary, indent=2) + "\n")
        return summary

    return _staged(Path(out), Path(map_path), write, "grid")


def slice_picture(e: Esdf, z: float | None) -> tuple[bytes, float]:
    """PNG of the horizontal slice of the field at height ``z`` (default: the middle of the region)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    nz = e.distance.shape[2]
    lo, hi = e.origin[2] - e.resolution / 2, e.origin[2] + (nz - 0.5) * e.resolution
    if z is not None and not lo <= z <= hi:
        raise ConfigError(f"--slice-z {z:g}: outside the field, which spans z {lo:.2f}..{hi:.2f} m (nothing was "
                          f"written)")
    k = nz // 2 if z is None else int(np.clip(round((z - e.origin[2]) / e.resolution), 0, nz - 1))
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

    return _staged(Path(out), Path(map_path), write, "esdf")


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


def _sequence_of_run(run: Path) -> tuple[Path | None, str]:
    """The dataset a run folder was made from (its config.json), when that path can be found, else None and why.
    A relative path is taken from where ``semmap run`` ran: the run folder less its relative ``output.out``."""
    try:
        config = json.loads((run / "config.json").read_text())
        path, out = Path(config["input"]["dataset"]), Path(config["output"]["out"])
    except (OSError, ValueError, KeyError, TypeError) as exc:
        return None, f"{run / 'config.json'} names no sequence ({type(exc).__name__}: {exc})"
    candidates = [path]
    here = run.resolve()
    if not path.is_absolute() and not out.is_absolute() and here.parts[-len(out.parts):] == out.parts:
        candidates.append(here.parents[len(out.parts) - 1] / path)  # the folder semmap run ran in
    found = next((c for c in candidates if c.exists()), None)
    return found, "" if found is not None else f"{run / 'config.json'} names the sequence {path}, which is not there"


def _rooms(run: Path, sequence: Path | None, door_width: float):
    """Rooms from the simulator's layout when the sequence is simulated, else a segmentation of the map's grid
    (with a warning when the run's own sequence cannot be found, or the grid holds no room)."""
    from semmap.datasets.simulated import scene_of_folder
    from semmap.products.rooms import rooms_from_boxes, rooms_from_grid

    if sequence is not None and not Path(sequence).is_dir():
        raise ConfigError(f"--sequence {sequence}: not a sequence folder")
    seq, missing = (Path(sequence), "") if sequence is not None else _sequence_of_run(run)
    scene = scene_of_folder(seq) if seq is not None and seq.is_dir() else None
    if scene is not None:
        return rooms_from_boxes([(r.name, r.bounds_min, r.bounds_max) for r in scene.rooms])
    if missing:
        LOG.warning(f"{missing}: rooms come from a segmentation of the map's grid (give --sequence SEQ for a "
                    f"simulated sequence's true rooms)")
    m, _ = load_product_map(run)
    rooms = rooms_from_grid(navigation_grid(occupancy_volume(m)), door_width=door_width)
    if not rooms.names:
        LOG.warning(f"{run}: the room segmentation of the map's grid found no room (no free cell lies "
                    f"{door_width / 2:g} m, half of --door-width, from every obstacle and unknown cell): the graph "
                    f"has objects but no rooms; a smaller --door-width, or a map that saw more of the floor, may "
                    f"find them")
    return rooms


def export_scene_graph(run: Path, out: Path, *, sequence: Path | None = None, near: float = 1.0,
                       door_width: float = 1.0) -> dict:
    """Write the scene graph of a run folder (its objects.json and map; rooms from ``sequence`` when simulated)."""
    from semmap.io.objects import read_objects_json
    from semmap.products.scene_graph import build_scene_graph, write_dsg

    run = Path(run)
    if not (run / "objects.json").is_file():
        raise FormatError(f"{run}: no objects.json; map with objects first (semmap run ... --instances oracle|"
                          f"components|maskrcnn)")
    objects = read_objects_json(run / "objects.json")
    graph = build_scene_graph(objects, _rooms(run, sequence, door_width), near=near)

    def write(stage: Path) -> dict:
        write_dsg(stage / "scene_graph.json", graph)
        summary = {"run": str(run), "rooms_from": graph.rooms.source, "rooms": list(graph.rooms.names),
                   "counts": graph.counts(),
                   "relations": [f"O{a} {kind} {'R' if kind == 'in' else 'O'}{b}" for kind, a, b in graph.relations]}
        write_text_atomic(stage / "graph.json", json.dumps(summary, indent=1) + "\n")
        return summary

    inputs = [("RUN", run)] + ([("--sequence", sequence)] if sequence is not None else [])
    return _staged(Path(out), inputs, write, "scene-graph")


def _objects_of(path: Path) -> list[dict] | None:
    from semmap.io.objects import read_objects_json

    folder = path if path.is_dir() else path.parent
    return read_objects_json(folder / "objects.json") if (folder / "objects.json").is_file() else None


def _object_points_of(path: Path) -> dict[int, np.ndarray]:
    """Each object's points (id -> (N, 3)) from the ``objects.ply`` beside a map; empty without one."""
    from semmap.io.objects import read_objects_ply

    folder = path if path.is_dir() else path.parent
    if not (folder / "objects.ply").is_file():
        return {}
    ply = read_objects_ply(folder / "objects.ply")
    if not len(ply["object"]):  # a run whose instances found nothing
        return {}
    order = np.argsort(ply["object"], kind="stable")
    ids, starts = np.unique(ply["object"][order], return_index=True)
    return {int(i): p for i, p in zip(ids, np.split(ply["points"][order], starts[1:]), strict=True)}


def diff_picture(changes, objects: dict | None) -> bytes:
    """Top-down picture of the changed voxels (and the moved objects' paths)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from semmap.products.changes import CHANGE_COLORS

    fig, ax = plt.subplots(figsize=(6, 6))
    for kind, pts in changes.centers.items():
        if len(pts):
            ax.scatter(pts[:, 0], pts[:, 1], s=2, color=np.array(CHANGE_COLORS[kind]) / 255,
                       label=f"{kind} ({len(pts):,} voxels)")
    for rec in (objects or {}).get("moved", []):
        (x0, y0, _), (x1, y1, _) = rec["from"], rec["to"]
        ax.annotate("", (x1, y1), (x0, y0), arrowprops={"arrowstyle": "->", "color": "black"})
        ax.text(x1, y1, f" {rec['class']}", fontsize=7)
    ax.set(xlabel="x (m)", ylabel="y (m)", title="what changed (top-down)", aspect="equal")
    if any(len(p) for p in changes.centers.values()):
        ax.legend(loc="best", fontsize=7)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100, bbox_inches="tight")
    plt.close(fig)
    return buf.getvalue()


def export_diff(before: Path, after: Path, out: Path, *, match_radius: float = 1.0,
                move_threshold: float = 0.2) -> dict:
    """Write what changed from ``before`` to ``after`` (maps or run folders in one frame) into ``out``."""
    from semmap.io.ply import write_ply
    from semmap.products.changes import CHANGE_COLORS, diff_objects, voxel_changes
    from semmap.types import MapCloud

    a, a_path = load_product_map(before)
    b, b_path = load_product_map(after)
    changes = voxel_changes(a, b)
    objs_a, objs_b = _objects_of(Path(before)), _objects_of(Path(after))
    objects = (diff_objects(objs_a, objs_b, a, b, match_radius=match_radius, move_threshold=move_threshold,
                            points=(_object_points_of(Path(before)), _object_points_of(Path(after))))
               if objs_a is not None and objs_b is not None else None)

    def write(stage: Path) -> dict:
        kinds = list(changes.centers)
        centers = np.concatenate([changes.centers[k] for k in kinds]).reshape(-1, 3)
        colors = np.concatenate([np.tile(CHANGE_COLORS[k], (len(changes.centers[k]), 1)) for k in kinds])
        labels = np.concatenate([changes.labels[k] for k in kinds]).astype(np.uint16)
        write_ply(stage / "diff.ply", MapCloud(centers, colors.astype(np.uint8).reshape(-1, 3), labels,
                                               np.ones(len(labels), np.float32), float(a.resolution)))
        write_bytes_atomic(stage / "diff.png", diff_picture(changes, objects))
        summary = {"before": str(a_path), "after": str(b_path), "resolution": float(a.resolution),
                   "voxels": {**changes.counts(), "observed_by_both": changes.observed_by_both,
                              "unobserved_in_one": changes.unobserved},
                   "objects": None if objects is None else {k: len(v) for k, v in objects.items()},
                   "object_changes": objects}
        write_text_atomic(stage / "diff.json", json.dumps(summary, indent=1) + "\n")
        return summary

    return _staged(Path(out), [("BEFORE", Path(before)), ("AFTER", Path(after))], write, "diff")


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
    from semmap.limits import check
    from semmap.maps.mesh import semantic_mesh

    check("tsdf_weight", min_weight, "--min-weight")
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

    return _staged(Path(out), Path(map_path), write, "mesh")
