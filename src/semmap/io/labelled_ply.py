"""Ground-truth points or mesh vertices with a class per vertex, from a PLY file of any writer.

ScanNet's ``*_vh_clean_2.labels.ply`` (binary little-endian: ``x y z red green blue alpha`` and a ``label`` ushort
of NYU-40 ids, then the faces), Replica's and Kimera's labelled meshes, and the clouds of ConceptGraphs'
evaluation all keep ``x y z`` and one integer class property on the ``vertex`` element. This reader takes ASCII
and binary (either byte order) files, any scalar property types, and reads only the vertex element (faces after
it are ignored; elements before it must have fixed-size rows).
"""

from __future__ import annotations

import mmap
from pathlib import Path

import numpy as np

from semmap.errors import FormatError
from semmap.files.safe import regular_file_size

#: PLY scalar types and their numpy codes (without byte order).
PLY_TYPES = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
             "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
             "float": "f4", "float32": "f4", "double": "f8", "float64": "f8"}
#: The header must end within this many bytes.
MAX_HEADER = 64 * 1024
_FORMATS = {"ascii": None, "binary_little_endian": "<", "binary_big_endian": ">"}


def _header(path: Path, raw) -> tuple[str, list[tuple[str, int, list[tuple[str, str | None]]]], int]:
    """(format, elements as (name, count, [(property, numpy code or None for a list)]), data offset)."""
    end = raw.find(b"end_header", 0, MAX_HEADER)
    if raw[:3] != b"ply" or end < 0:
        raise FormatError(f"{path}: not a PLY file (no 'ply' ... 'end_header')")
    start = raw.find(b"\n", end) + 1
    lines = raw[:end].decode("ascii", "replace").splitlines()
    fmt, elements = None, []
    try:
        for line in lines[1:]:
            words = line.split()
            if not words or words[0] in ("comment", "obj_info"):
                continue
            if words[0] == "format":
                fmt = words[1]
            elif words[0] == "element":
                elements.append((words[1], int(words[2]), []))
                if elements[-1][1] < 0:
                    raise ValueError(line)
            elif words[0] == "property" and elements:
                is_list = words[1] == "list"
                code = None if is_list else PLY_TYPES[words[1]]
                elements[-1][2].append((words[-1], code))
    except (IndexError, ValueError, KeyError):
        raise FormatError(f"{path}: malformed PLY header line {line!r}") from None
    if fmt not in _FORMATS:
        raise FormatError(f"{path}: unknown PLY format {fmt!r} (ascii, binary_little_endian, binary_big_endian)")
    return fmt, elements, start


def read_vertex_rows(path: str | Path, *, what: str = "PLY file") -> np.ndarray:
    """Every property of the vertex element of a PLY (structured array, one field per property), ``x y z``
    checked finite; FormatError naming the file otherwise."""
    path = Path(path)
    size = regular_file_size(path, what=what)
    if size == 0:
        raise FormatError(f"{path}: file is empty")
    with open(path, "rb") as f:
        try:
            raw = mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ)
        except (OSError, ValueError) as exc:
            raise FormatError(f"{path}: cannot read ({exc})") from None
    fmt, elements, offset = _header(path, raw)
    names = [e[0] for e in elements]
    if "vertex" not in names:
        raise FormatError(f"{path}: no vertex element")
    v = names.index("vertex")
    _, count, props = elements[v]
    have = [p for p, _ in props]
    for needed in ("x", "y", "z"):
        if needed not in have:
            raise FormatError(f"{path}: the vertices have no {needed!r} property (they have {', '.join(have)})")
    if any(code is None for _, code in props) or any(c is None for e in elements[:v] for _, c in e[2]):
        raise FormatError(f"{path}: list properties on or before the vertex element are not supported")
    rows = _ascii_rows(path, raw, offset, elements[:v], count, props) if fmt == "ascii" else \
        _binary_rows(path, raw, offset, elements[:v], count, props, _FORMATS[fmt])
    points = np.stack([rows[c] for c in ("x", "y", "z")], 1)
    if not np.isfinite(points).all():
        raise FormatError(f"{path}: {int((~np.isfinite(points)).any(1).sum()):,} vertices with non-finite coordinates")
    return rows


def read_labelled_vertices(path: str | Path, label_property: str = "label") -> tuple[np.ndarray, np.ndarray]:
    """(N, 3) float64 vertex positions and (N,) int64 classes (the ``label_property`` of each vertex) of a PLY."""
    rows = read_vertex_rows(path, what="ground-truth PLY")
    if label_property not in (rows.dtype.names or ()):
        raise FormatError(f"{path}: the vertices have no {label_property!r} property (they have "
                          f"{', '.join(rows.dtype.names or ())}); name the class property with --gt-label-property")
    points = np.stack([rows[c] for c in ("x", "y", "z")], 1).astype(np.float64)
    labels = np.asarray(rows[label_property])
    if labels.dtype.kind == "f" and not (np.isfinite(labels).all() and (labels == np.round(labels)).all()):
        raise FormatError(f"{path}: property {label_property!r} holds non-integer classes")
    return points, labels.astype(np.int64)


def _binary_rows(path: Path, raw, offset: int, before, count: int, props, order: str) -> np.ndarray:
    dtype = np.dtype([(name, order + code) for name, code in props])
    for _, n, pp in before:
        offset += n * np.dtype([(name, order + code) for name, code in pp]).itemsize
    if count < 0 or offset + count * dtype.itemsize > len(raw):
        raise FormatError(f"{path}: truncated PLY ({count:,} vertices of {dtype.itemsize} bytes announced)")
    return np.frombuffer(raw, dtype, count=count, offset=offset).copy()


def _ascii_rows(path: Path, raw, offset: int, before, count: int, props) -> np.ndarray:
    skip = sum(n for _, n, _ in before)
    lines = raw[offset:].decode("ascii", "replace").split("\n")
    body = [line for line in lines[skip:skip + count]]
    if len(body) < count:
        raise FormatError(f"{path}: truncated PLY ({len(body):,} of {count:,} vertex lines)")
    try:
        values = np.array([line.split()[: len(props)] for line in body], np.float64).reshape(count, len(props))
    except ValueError:
        raise FormatError(f"{path}: malformed vertex line in ASCII PLY") from None
    rows = np.empty(count, [(name, "f8") for name, _ in props])
    for i, (name, _) in enumerate(props):
        rows[name] = values[:, i]
    return rows
