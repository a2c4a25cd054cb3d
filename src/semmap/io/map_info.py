"""What ``semmap info`` says about a map file, whichever map wrote it."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from semmap.errors import FormatError
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


def _format_of(path: Path) -> str | None:
    from semmap.io.safe_files import read_npz_members

    raw = read_npz_members(path, ["header"], what="semmap map")["header"]
    try:
        header = json.loads(raw.tobytes().decode("utf-8"))
    except (UnicodeDecodeError, ValueError) as exc:
        raise FormatError(f"{path}: header is not JSON ({exc})") from None
    return header.get("format") if isinstance(header, dict) else None


def _describe_semmap(path: Path) -> dict:
    from semmap.io.grid_files import FORMAT as GRID_FORMAT
    from semmap.io.grid_files import load_grid

    if _format_of(path) == GRID_FORMAT:
        m = load_grid(path)
        return {"kind": m.kind.value, "resolution": m.resolution, **m.describe(),
                "classes": None if m.label_set is None else len(m.label_set)}
    from semmap.io.native import load_map

    m = load_map(path)
    return {"kind": "semmap", "resolution": m.resolution, "voxels": m.num_leaves, "occupied": m.num_occupied,
            "free": m.num_free, "fusion": m.fusion.name, "classes": None if m.label_set is None else len(m.label_set)}
