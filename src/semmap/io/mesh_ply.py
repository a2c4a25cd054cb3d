"""``mesh.ply``: the semantic mesh as binary little-endian PLY (Open3D, trimesh, MeshLab and plyfile read it).

``vertex``: ``x y z`` float32, ``red green blue`` uchar, ``label`` ushort (65535 = no class), ``confidence`` float32,
then the class distribution: ``prob_0 .. prob_{K-1}`` float32 for up to :data:`MAX_DENSE_CLASSES` classes, else the
top :data:`TOP_K` as ``top_label_i`` ushort / ``top_prob_i`` float32. ``face``: ``vertex_indices`` (uchar count,
int32 indices), counter-clockwise seen from the free side.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from semmap.files.atomic import write_atomic
from semmap.maps.mesh import SemanticMesh
from semmap.types import EMPTY_LABEL

#: Label sets up to this size get every class probability per vertex; bigger ones their top-k.
MAX_DENSE_CLASSES = 64
TOP_K = 3
_PLY_TYPES = {"<f4": "float", "u1": "uchar", "<u2": "ushort"}


def _vertex_fields(mesh: SemanticMesh) -> list[tuple[str, str]]:
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1"),
              ("label", "<u2"), ("confidence", "<f4")]
    if mesh.probs is None:
        return fields
    k = mesh.probs.shape[1]
    if k <= MAX_DENSE_CLASSES:
        return fields + [(f"prob_{c}", "<f4") for c in range(k)]
    return fields + [f for i in range(TOP_K) for f in ((f"top_label_{i}", "<u2"), (f"top_prob_{i}", "<f4"))]


def write_mesh_ply(path: str | Path, mesh: SemanticMesh) -> int:
    """Write ``mesh`` atomically; returns the file size in bytes."""
    fields = _vertex_fields(mesh)
    rows = np.zeros(len(mesh), dtype=fields)
    rows["x"], rows["y"], rows["z"] = mesh.vertices.T
    rows["red"], rows["green"], rows["blue"] = mesh.colors.T
    rows["label"], rows["confidence"] = mesh.labels, mesh.confidence
    if mesh.probs is not None and mesh.probs.shape[1] <= MAX_DENSE_CLASSES:
        for c in range(mesh.probs.shape[1]):
            rows[f"prob_{c}"] = mesh.probs[:, c]
    elif mesh.probs is not None:
        top = np.argsort(-mesh.probs, axis=1, kind="stable")[:, :TOP_K]
        p = np.take_along_axis(mesh.probs, top, axis=1)
        for i in range(TOP_K):
            rows[f"top_label_{i}"] = np.where(p[:, i] > 0, top[:, i], EMPTY_LABEL)
            rows[f"top_prob_{i}"] = p[:, i]
    faces = np.empty(len(mesh.faces), dtype=[("n", "u1"), ("v", "<i4", (3,))])
    faces["n"], faces["v"] = 3, mesh.faces
    names = "" if mesh.label_set is None else " ".join(mesh.label_set.names).replace("\n", " ")
    header = ["ply", "format binary_little_endian 1.0", "comment semmap semantic mesh (label 65535 = no class)",
              f"comment resolution {mesh.resolution!r}", *([f"comment classes {names}"] if names else []),
              f"element vertex {len(mesh)}"]
    header += [f"property {_PLY_TYPES[t]} {name}" for name, t in fields]
    header += [f"element face {len(faces)}", "property list uchar int vertex_indices", "end_header"]
    data = ("\n".join(header) + "\n").encode("ascii", "replace") + rows.tobytes() + faces.tobytes()
    write_atomic(path, lambda f: f.write(data))
    return Path(path).stat().st_size
