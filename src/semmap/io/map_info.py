"""What ``semmap info`` says about a map file, whichever map wrote it."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from semmap.errors import FormatError
from semmap.maps.registry import MapKind
from semmap.types import EMPTY_LABEL


def describe_map_file(path: str | Path) -> dict:
    """Kind, resolution and counts of a ``.ot`` / ``.bt`` / ``.semmap`` / ``.ply`` map file, or the points, objects
    and classes of an ``objects.ply`` (FormatError otherwise)."""
    path = Path(path)
    if path.suffix == ".semmap":
        return _describe_semmap(path)
    if path.suffix == ".ply":
        from semmap.io.objects import is_objects_ply
        from semmap.io.ply import read_ply

        if is_objects_ply(path):
            return _describe_objects_ply(path)

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
    raise FormatError(f"{path}: unknown map file type {path.suffix!r} (expected .ot, .bt, .semmap or .ply)")


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
