"""What ``semmap info`` says about a map file, whichever map wrote it."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from semmap.errors import FormatError
from semmap.maps.registry import MapKind
from semmap.types import EMPTY_LABEL


def describe_map_file(path: str | Path) -> dict:
    """Kind, resolution and counts of a ``.ot`` / ``.bt`` / ``.semmap`` / ``.ply`` map file, the points, objects
    and classes of an ``objects.ply``, the vertices and triangles of a ``mesh.ply``, or what a product file holds
    (``io.product_info``: grids, costmaps, ESDF, scene graph, summaries, trajectories); FormatError otherwise."""
    path = Path(path)
    if path.suffix == ".semmap":
        return _describe_semmap(path)
    if path.suffix == ".ply":
        from semmap.io.mesh_ply import is_mesh_ply
        from semmap.io.objects import is_objects_ply
        from semmap.io.ply import read_ply

        if is_objects_ply(path):
            return _describe_objects_ply(path)
        if is_mesh_ply(path):
            return _describe_mesh(path)
        if not _is_semmap_cloud(path):
            return _describe_plain_ply(path)

        cloud = read_ply(path)
        labelled = cloud.labels != EMPTY_LABEL
        return {"kind": "ply", "resolution": cloud.resolution, "points": len(cloud),
                "labelled": int(labelled.sum()), "classes_present": int(np.unique(cloud.labels[labelled]).size),
                "normals": cloud.normals is not None}
    if path.suffix in (".ot", ".bt"):
        from semmap.io.octomap_files import read_octomap

        leaves = read_octomap(path)
        occ = leaves.occupied()
        return {"kind": leaves.tree_type, "resolution": leaves.resolution, "nodes": leaves.num_nodes,
                "occupied_leaves": int(occ.sum()), "free_leaves": int((~occ).sum())}
    from semmap.io.product_info import describe_product_file

    return describe_product_file(path)


def _is_semmap_cloud(path: Path) -> bool:
    """Whether a PLY's header has the label and confidence of semmap's map clouds (else it is any point cloud)."""
    from semmap.io.ply import MAX_PLY_HEADER

    try:
        with open(path, "rb") as f:
            head = f.read(MAX_PLY_HEADER)
    except OSError:
        return True  # the map PLY reader names the problem
    names = [line.split()[-1] for line in head.split(b"end_header")[0].decode("ascii", "replace").splitlines()
             if line.startswith("property")]
    return not names or {"label", "confidence"} <= set(names)


def _describe_mesh(path: Path) -> dict:
    from semmap.io.mesh_ply import read_mesh_ply

    mesh = read_mesh_ply(path)
    labelled = mesh.labels != EMPTY_LABEL
    names = mesh.label_set.names if mesh.label_set is not None else None
    ids, counts = np.unique(mesh.labels[labelled], return_counts=True)
    return {"kind": "mesh", "resolution": mesh.resolution, "vertices": len(mesh), "triangles": len(mesh.faces),
            "labelled_share": round(float(labelled.mean()), 4) if len(mesh) else 0.0,
            "vertices_per_class": {(names[i] if names is not None and i < len(names) else f"class {i}"): int(n)
                                   for i, n in zip(ids, counts, strict=True)}}


def _describe_plain_ply(path: Path) -> dict:
    """Any point cloud PLY (``cloud.ply``: points and colours): its vertex count and properties."""
    from semmap.io.labelled_ply import read_vertex_rows

    rows = read_vertex_rows(path)
    points = np.stack([rows[c] for c in ("x", "y", "z")], 1).astype(np.float64)
    lo, hi = (points.min(axis=0), points.max(axis=0)) if len(points) else (np.zeros(3), np.zeros(3))
    return {"kind": "point cloud", "points": len(points), "properties": list(rows.dtype.names or ()),
            "bounds_m": [[round(float(v), 3) for v in lo], [round(float(v), 3) for v in hi]]}


def _describe_semmap(path: Path) -> dict:
    from semmap.io.map_files import load_map

    m = load_map(path)
    if m.kind != MapKind.OCTOMAP:
        return {"kind": m.kind.value, "resolution": m.resolution, **m.describe(),
                "classes": None if m.label_set is None else len(m.label_set)}
    return {"kind": "semmap", "resolution": m.resolution, "voxels": m.num_leaves, "occupied": m.num_occupied,
            "free": m.num_free, "fusion": m.fusion.name, "classes": None if m.label_set is None else len(m.label_set)}


def _describe_objects_ply(path: Path) -> dict:
    """An ``objects.ply`` of ``semmap run --instances``: its points, objects and objects per class (named from the
    ``objects.json`` beside it when that one is readable, else by class id)."""
    from semmap.io.objects import read_objects_json, read_objects_ply

    ply = read_objects_ply(path)
    pairs = np.unique(np.stack([ply["object"].astype(np.int64), ply["label"].astype(np.int64)], 1), axis=0)
    try:
        names = {int(r["class_id"]): str(r["class"]) for r in read_objects_json(path.with_name("objects.json"))
                 if "class_id" in r}
    except FormatError:
        names = {}
    ids, counts = np.unique(pairs[:, 1], return_counts=True)
    per_class = {names.get(int(i), f"class {int(i)}"): int(n) for i, n in zip(ids, counts, strict=True)}
    return {"kind": "objects", "points": len(ply["object"]), "objects": int(np.unique(pairs[:, 0]).size),
            "classes_present": len(per_class), "objects_per_class": per_class}
