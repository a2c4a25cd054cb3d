"""Files of the object map: ``objects.json`` (one record per object) and ``objects.ply`` (every object's points).

``objects.json``: ``{"format": "semmap-objects", "version": 1, "up": [x, y, z], "objects": [...]}``; per object
``id``, ``class``, ``class_id``, ``confidence`` (share of its class votes), ``centroid`` (metres, world frame),
``box`` (``center``, ``rotation`` 3x3 with the box axes as columns, ``extent``: an upright oriented box),
``points``, ``sightings`` (keyframes), ``first_frame``, ``last_frame``, ``track_ids``.
``objects.ply``: binary little-endian, one ``vertex`` per point: ``x y z`` float32, ``red green blue`` uchar (the
object's display colour), ``object`` int (its id), ``label`` ushort (its class).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from semmap.errors import FormatError
from semmap.files.atomic import write_atomic, write_text_atomic
from semmap.maps.objects import MapObject, upright_box
from semmap.types import LabelSet, MapCloud, distinct_colors

FORMAT = "semmap-objects"
VERSION = 1
_PLY_FIELDS = [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1"),
               ("object", "<i4"), ("label", "<u2")]
_PLY_TYPES = {"<f4": "float", "u1": "uchar", "<u2": "ushort", "<i4": "int"}


def object_records(objects: list[MapObject], label_set: LabelSet, up: np.ndarray) -> list[dict]:
    """The JSON records of ``objects`` (see the module docstring)."""
    out = []
    for o in objects:
        box = upright_box(o.points, up)
        out.append({"id": o.id, "class": label_set.names[o.class_id], "class_id": o.class_id,
                    "confidence": round(o.confidence, 4), "centroid": _rounded(o.centroid),
                    "box": {"center": _rounded(box.center), "rotation": [_rounded(r) for r in box.rotation],
                            "extent": _rounded(box.extent)},
                    "points": len(o), "sightings": o.sightings, "first_frame": o.first_frame,
                    "last_frame": o.last_frame, "track_ids": sorted(o.track_ids)})
    return out


def write_objects_json(path: str | Path, objects: list[MapObject], label_set: LabelSet, up: np.ndarray) -> int:
    """Write ``objects.json`` atomically; returns its size in bytes."""
    doc = {"format": FORMAT, "version": VERSION, "up": _rounded(up), "objects": object_records(objects, label_set, up)}
    write_text_atomic(path, json.dumps(doc, indent=1) + "\n")
    return Path(path).stat().st_size


def read_objects_json(path: str | Path) -> list[dict]:
    """The object records of an ``objects.json`` written by :func:`write_objects_json` (validated)."""
    path = Path(path)
    try:
        doc = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError) as exc:
        raise FormatError(f"{path}: cannot read ({exc})") from None
    except json.JSONDecodeError as exc:
        raise FormatError(f"{path}: not JSON ({exc.msg}, line {exc.lineno})") from None
    if not isinstance(doc, dict) or doc.get("format") != FORMAT or not isinstance(doc.get("objects"), list):
        raise FormatError(f"{path}: not a semmap objects file (needs format {FORMAT!r} and an objects list)")
    for i, rec in enumerate(doc["objects"]):
        try:
            if len(rec["centroid"]) != 3 or len(rec["box"]["extent"]) != 3 or len(rec["box"]["rotation"]) != 3:
                raise ValueError("centroid, box extent and rotation need 3 entries")
            int(rec["id"]), str(rec["class"]), int(rec["points"]), int(rec["sightings"])
        except (KeyError, TypeError, ValueError) as exc:
            raise FormatError(f"{path}: object {i} is malformed ({exc})") from None
    return doc["objects"]


def object_colors(n: int) -> np.ndarray:
    """(n, 3) uint8 display colours for objects 1..n (by id), well spread and never black."""
    return distinct_colors(n + 1)[1:]


def write_objects_ply(path: str | Path, objects: list[MapObject]) -> int:
    """Write every object's points, coloured per object, as binary little-endian PLY; returns the size in bytes."""
    n = sum(len(o) for o in objects)
    rows = np.empty(n, dtype=_PLY_FIELDS)
    palette = object_colors(max([o.id for o in objects], default=0))
    i = 0
    for o in objects:
        sl = slice(i, i + len(o))
        rows["x"][sl], rows["y"][sl], rows["z"][sl] = o.points.T
        rows["red"][sl], rows["green"][sl], rows["blue"][sl] = palette[o.id - 1]
        rows["object"][sl], rows["label"][sl] = o.id, o.class_id
        i += len(o)
    header = ["ply", "format binary_little_endian 1.0", "comment semmap objects (object = id in objects.json)",
              f"element vertex {n}"] + [f"property {_PLY_TYPES[t]} {name}" for name, t in _PLY_FIELDS] + ["end_header"]
    data = ("\n".join(header) + "\n").encode("ascii") + rows.tobytes()
    write_atomic(path, lambda f: f.write(data))
    return Path(path).stat().st_size


def is_objects_ply(path: str | Path) -> bool:
    """Whether ``path`` is a PLY whose header has the ``object`` property of ``objects.ply`` (not a map's PLY);
    False for anything unreadable, which the map PLY reader then names."""
    from semmap.files.safe import regular_file_size
    from semmap.io.ply import MAX_PLY_HEADER

    try:
        regular_file_size(path, what="PLY file")
        with open(path, "rb") as f:
            head = f.read(MAX_PLY_HEADER)
    except (OSError, FormatError):
        return False
    end = head.find(b"end_header\n")
    return head.startswith(b"ply\n") and end >= 0 and b"\nproperty int object\n" in head[:end]


def read_objects_ply(path: str | Path) -> dict[str, np.ndarray]:
    """``points`` (N, 3) float32, ``colors`` (N, 3) uint8, ``object`` (N,) int32, ``label`` (N,) uint16 of a PLY
    written by :func:`write_objects_ply`."""
    from semmap.files.safe import regular_file_size

    path = Path(path)
    regular_file_size(path, what="PLY file")  # never a FIFO or a device
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise FormatError(f"{path}: cannot read ({exc.strerror or exc})") from None
    end = raw.find(b"end_header\n")
    if not raw.startswith(b"ply\n") or end < 0:
        raise FormatError(f"{path}: not a PLY file (no 'ply' / 'end_header')")
    lines = raw[:end].decode("ascii", "replace").splitlines()
    names = [line.split()[2] for line in lines if line.startswith("property")]
    if "format binary_little_endian 1.0" not in lines or names != [n for n, _ in _PLY_FIELDS]:
        raise FormatError(f"{path}: not an objects PLY written by semmap (properties {names})")
    try:
        n = next(int(line.split()[2]) for line in lines if line.startswith("element vertex"))
    except (StopIteration, IndexError, ValueError):
        raise FormatError(f"{path}: malformed PLY header") from None
    dtype = np.dtype(_PLY_FIELDS)
    body = raw[end + len(b"end_header\n"):]
    if len(body) != n * dtype.itemsize:
        raise FormatError(f"{path}: truncated PLY ({len(body)} bytes of vertex data, expected {n * dtype.itemsize})")
    rows = np.frombuffer(body, dtype)
    return {"points": np.stack([rows["x"], rows["y"], rows["z"]], 1).astype(np.float32),
            "colors": np.stack([rows["red"], rows["green"], rows["blue"]], 1).astype(np.uint8),
            "object": rows["object"].astype(np.int32), "label": rows["label"].astype(np.uint16)}


#: Size (m) of the cells an ``objects.ply``'s points are drawn as (the file holds points, no voxel size).
OBJECT_POINT_SIZE = 0.02


def objects_ply_cloud(path: str | Path) -> MapCloud:
    """The points of an ``objects.ply`` as a cloud a viewer draws: each in its object's colour, with its class
    id, at :data:`OBJECT_POINT_SIZE`."""
    ply = read_objects_ply(path)
    n = len(ply["label"])
    return MapCloud(ply["points"].astype(np.float64), ply["colors"], ply["label"], np.zeros(n, np.float32),
                    OBJECT_POINT_SIZE)


def _rounded(v) -> list[float]:
    return [round(float(x), 6) for x in np.asarray(v, np.float64).ravel()]
