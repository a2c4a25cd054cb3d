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


#: The header comment that marks semmap's semantic mesh.
MESH_COMMENT = "comment semmap semantic mesh"


def is_mesh_ply(path: str | Path) -> bool:
    """Whether ``path`` is a PLY with a ``face`` element (a mesh, not a map's or an object's point cloud); False for
    anything unreadable, which the other PLY readers then name."""
    from semmap.errors import FormatError
    from semmap.files.safe import regular_file_size
    from semmap.io.ply import MAX_PLY_HEADER

    try:
        regular_file_size(path, what="PLY file")
        with open(path, "rb") as f:
            head = f.read(MAX_PLY_HEADER)
    except (OSError, FormatError):
        return False
    end = head.find(b"end_header")
    return end >= 0 and any(line.startswith("element face") for line in
                            head[:end].decode("ascii", "replace").splitlines())


def read_mesh_ply(path: str | Path) -> SemanticMesh:
    """A ``mesh.ply`` written by :func:`write_mesh_ply` (or any binary little-endian triangle mesh PLY with ``x y z``
    and optionally ``red green blue``, ``label``, ``confidence``) as a :class:`SemanticMesh`; FormatError naming the
    file otherwise."""
    import mmap

    from semmap.errors import FormatError
    from semmap.files.safe import regular_file_size
    from semmap.io.labelled_ply import PLY_TYPES
    from semmap.io.ply import MAX_PLY_HEADER
    from semmap.labels import INDOOR_LABELS
    from semmap.types import LabelSet, distinct_colors

    path = Path(path)
    if regular_file_size(path, what="mesh PLY") == 0:
        raise FormatError(f"{path}: file is empty")
    try:  # memory-mapped: the header is checked against the file's size before the data is touched
        with open(path, "rb") as f:
            raw = mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ)
    except (OSError, ValueError) as exc:
        raise FormatError(f"{path}: cannot read ({getattr(exc, 'strerror', None) or exc})") from None
    end = raw.find(b"end_header\n", 0, MAX_PLY_HEADER)
    if raw[:4] != b"ply\n" or end < 0:
        raise FormatError(f"{path}: not a PLY file (no 'ply' / 'end_header')")
    lines = raw[:end].decode("ascii", "replace").splitlines()
    if "format binary_little_endian 1.0" not in lines:
        raise FormatError(f"{path}: only binary little-endian mesh PLY is read here")
    elements: dict[str, tuple[int, list]] = {}
    current = None
    try:
        for line in lines:
            words = line.split()
            if words[:1] == ["element"]:
                current = words[1]
                elements[current] = (int(words[2]), [])
            elif words[:1] == ["property"] and current is not None:
                elements[current][1].append(words[1:])
    except (IndexError, ValueError):
        raise FormatError(f"{path}: malformed PLY header") from None
    if list(elements) != ["vertex", "face"]:
        raise FormatError(f"{path}: a mesh PLY has a vertex and a face element, got {list(elements)}")
    try:
        vertex = np.dtype([(p[1], "<" + PLY_TYPES[p[0]]) for p in elements["vertex"][1]])
    except (KeyError, IndexError):
        raise FormatError(f"{path}: unexpected vertex property types") from None
    if elements["face"][1] != [["list", "uchar", "int", "vertex_indices"]]:
        raise FormatError(f"{path}: faces must be 'property list uchar int vertex_indices'")
    nv, nf = elements["vertex"][0], elements["face"][0]
    face = np.dtype([("n", "u1"), ("v", "<i4", (3,))])
    start = end + len(b"end_header\n")
    if len(raw) - start != nv * vertex.itemsize + nf * face.itemsize:
        raise FormatError(f"{path}: truncated or not triangles ({len(raw) - start} bytes after the header, expected "
                          f"{nv * vertex.itemsize + nf * face.itemsize})")
    rows = np.frombuffer(raw, vertex, count=nv, offset=start).copy()
    faces = np.frombuffer(raw, face, count=nf, offset=start + nv * vertex.itemsize).copy()
    if nf and (np.any(faces["n"] != 3) or faces["v"].min() < 0 or faces["v"].max() >= nv):
        raise FormatError(f"{path}: faces must be triangles of vertices 0..{nv - 1}")
    names = vertex.names
    if not {"x", "y", "z"} <= set(names):
        raise FormatError(f"{path}: vertices without x y z")
    xyz = np.stack([rows["x"], rows["y"], rows["z"]], 1).astype(np.float32)
    if not np.isfinite(xyz).all():
        raise FormatError(f"{path}: non-finite vertex coordinates")
    rgb = (np.stack([rows["red"], rows["green"], rows["blue"]], 1).astype(np.uint8)
           if {"red", "green", "blue"} <= set(names) else np.full((nv, 3), 160, np.uint8))
    labels = rows["label"].astype(np.uint16) if "label" in names else np.full(nv, EMPTY_LABEL, np.uint16)
    confidence = rows["confidence"].astype(np.float32) if "confidence" in names else np.zeros(nv, np.float32)
    classes = next((line.split()[2:] for line in lines if line.startswith("comment classes ")), None)
    label_set = None
    if classes:
        label_set = (INDOOR_LABELS if tuple(classes) == INDOOR_LABELS.names
                     else LabelSet(tuple(classes), distinct_colors(len(classes))))
    try:
        resolution = next((float(line.split()[2]) for line in lines if line.startswith("comment resolution ")
                           and len(line.split()) > 2), 0.0)
    except ValueError:
        raise FormatError(f"{path}: malformed 'comment resolution' line") from None
    return SemanticMesh(xyz, faces["v"].astype(np.int32), rgb, labels, confidence, None, label_set, resolution,
                        np.zeros(nv, bool))
