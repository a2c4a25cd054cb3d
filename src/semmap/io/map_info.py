"""What ``semmap info`` says about a map file, whichever map wrote it."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from semmap.errors import FormatError
from semmap.maps.registry import MapKind
from semmap.types import EMPTY_LABEL


def describe_map_file(path: str | Path) -> dict:
    """Kind, resolution and counts of a ``.ot`` / ``.bt`` / ``.semmap`` / ``.ply`` map file (FormatError otherwise)."""
    path = Path(path)
    if path.suffix == ".semmap":
        return _describe_semmap(path)
    if path.suffix == ".ply":
        from semmap.io.ply import read_ply

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
