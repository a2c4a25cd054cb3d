"""What ``semmap info`` says about the files semmap writes beside its maps: the products of ``export`` and ``diff``
(grids, costmaps, ESDF, scene graph, their summaries), trajectories, transforms, objects and a run's JSON records."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from semmap.errors import FormatError
from semmap.io.product_files import (
    read_costmap_npy,
    read_esdf_npz,
    read_image,
    read_json_limited,
    read_map_server,
    read_scene_graph,
    yaml_of_image,
)

#: The JSON summaries semmap writes beside its products, and what each describes.
SUMMARIES = {"grid.json": "grid summary", "esdf.json": "esdf summary", "graph.json": "scene graph summary",
             "diff.json": "diff", "mesh.json": "mesh summary", "merge.json": "merge summary",
             "report.json": "run report", "config.json": "run configuration", "batch.json": "batch summary"}
#: What ``semmap info`` opens, for the message about anything else.
KINDS = (".ot, .bt, .semmap, .ply (map clouds, objects.ply, mesh.ply), map_server grids (.yaml, .pgm, .png), images, "
         "costmap.npy, esdf.npz, localization.npz, scene_graph.json, objects.json, the JSON summaries and records "
         "(grid.json, diff.json, report.json, ...), TUM trajectories and transform.txt")


def describe_product_file(path: Path) -> dict:
    """The description of a product file (module docstring), or a FormatError naming what ``info`` opens."""
    suffix = path.suffix
    if suffix in (".pgm", ".png") and yaml_of_image(path) is None:
        return _image(path)
    if suffix in (".yaml", ".pgm", ".png"):
        return _grid(read_map_server(path))
    if suffix == ".npy":
        return _grid(read_costmap_npy(path))
    if suffix == ".npz":
        return _npz(path)
    if suffix == ".json":
        return _json(path)
    if suffix == ".txt":
        return _text(path)
    raise FormatError(f"{path}: unknown file type {suffix!r} (semmap info opens {KINDS})")


def _image(path: Path) -> dict:
    """A picture semmap drew (preview.png, esdf_slice.png, diff.png, the report's plots)."""
    pixels = read_image(path)
    return {"kind": "image", "width": int(pixels.shape[1]), "height": int(pixels.shape[0]),
            "channels": 1 if pixels.ndim == 2 else int(pixels.shape[2])}


def _grid(g) -> dict:
    cells = g.cells
    out = {"kind": "map_server grid" if g.mode != "raw" else "costmap", "file": str(g.image), "mode": g.mode,
           "resolution": g.resolution, "origin": [round(float(v), 4) for v in g.origin],
           "size_cells": [int(n) for n in cells.shape], "unknown": int((cells < 0).sum()),
           "free": int((cells == 0).sum()), "occupied": int((cells == 100).sum())}
    between = (cells > 0) & (cells < 100)
    if between.any():
        out["cost_1_to_99"] = int(between.sum())
    return out


def _npz(path: Path) -> dict:
    try:
        with np.load(path, allow_pickle=False) as z:
            names = list(z.files)
    except (OSError, ValueError) as exc:
        raise FormatError(f"{path}: not a NumPy archive ({exc})") from None
    if "distance" in names:
        e = read_esdf_npz(path)
        d = e["distance"]
        finite = d[np.isfinite(d)]
        return {"kind": "esdf", "resolution": float(e["resolution"]), "origin": [round(float(v), 4)
                                                                                for v in e["origin"]],
                "size_voxels": [int(n) for n in d.shape], "observed_share": round(float(e["observed"].mean()), 4),
                "inside_obstacles": int((d < 0).sum()), "max_distance_m": round(float(finite.max()), 4)
                if finite.size and finite.max() > 0 else None}
    with np.load(path, allow_pickle=False) as z:
        return {"kind": "localization" if "particles" in " ".join(names) or path.stem == "localization" else "npz",
                "arrays": {n: [int(s) for s in z[n].shape] for n in names}}


def _json(path: Path) -> dict:
    if path.name == "scene_graph.json":
        nodes, edges = read_scene_graph(path)
        relations: dict[str, int] = {}
        for kind, _, _ in edges:
            relations[kind] = relations.get(kind, 0) + 1
        return {"kind": "scene graph", "objects": sum(n.layer == "object" for n in nodes),
                "rooms": [n.name for n in nodes if n.layer == "room"], "relations": relations}
    data = read_json_limited(path, "JSON file")
    if isinstance(data, dict) and data.get("format") == "semmap-objects":
        per_class: dict[str, int] = {}
        for o in data.get("objects", []):
            per_class[str(o.get("class"))] = per_class.get(str(o.get("class")), 0) + 1
        return {"kind": "objects", "objects": len(data.get("objects", [])), "objects_per_class": per_class}
    if path.name not in SUMMARIES or not isinstance(data, dict):
        raise FormatError(f"{path}: not a JSON file semmap writes (semmap info opens {KINDS})")
    if path.name in ("report.json", "config.json"):
        return {"kind": SUMMARIES[path.name], "keys": sorted(data)}
    return {"kind": SUMMARIES[path.name], **{("map_kind" if k == "kind" else k): v for k, v in data.items()
                                             if k not in ("relations", "object_changes")}}


def _text(path: Path) -> dict:
    """A TUM trajectory, or the 4x4 transform of ``semmap merge``."""
    from semmap.files.safe import read_text_limited

    rows = [line.split() for line in read_text_limited(path, what="text file").splitlines()
            if line.strip() and not line.lstrip().startswith("#")]
    if len(rows) == 4 and all(len(r) == 4 for r in rows):
        try:
            T = np.array(rows, np.float64)
        except ValueError:
            raise FormatError(f"{path}: 4 rows of 4 values, but not numbers") from None
        return {"kind": "transform", "translation_m": [round(float(v), 4) for v in T[:3, 3]],
                "rotation_deg": round(float(np.degrees(np.arccos(np.clip((np.trace(T[:3, :3]) - 1) / 2, -1, 1)))),
                                      3)}
    from semmap.io.trajectory import read_trajectory

    traj = read_trajectory(path)
    steps = np.linalg.norm(np.diff(traj.poses[:, :3, 3], axis=0), axis=1)
    return {"kind": "trajectory", "poses": len(traj.timestamps),
            "seconds": round(float(traj.timestamps[-1] - traj.timestamps[0]), 3),
            "path_length_m": round(float(steps.sum()), 3)}
