"""Binary PLY of a map's voxels or points (CloudCompare, Open3D, MeshLab open it).

One ``vertex`` element, little-endian: ``x y z`` float32, ``red green blue`` uchar, ``label`` ushort (65535 =
no class), ``confidence`` float32, and ``nx ny nz`` float32 when the map keeps normals.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from semmap.errors import FormatError
from semmap.files.atomic import write_atomic
from semmap.limits import check_file_resolution
from semmap.types import MapCloud

_BASE = [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1"),
         ("label", "<u2"), ("confidence", "<f4")]
_NORMALS = [("nx", "<f4"), ("ny", "<f4"), ("nz", "<f4")]
_PLY_TYPES = {"<f4": "float", "u1": "uchar", "<u2": "ushort"}


def write_ply(path: str | Path, cloud: MapCloud) -> int:
    """Write ``cloud`` as binary little-endian PLY atomically; returns the file size in bytes."""
    fields = _BASE + (_NORMALS if cloud.normals is not None else [])
    rows = np.empty(len(cloud), dtype=fields)
    rows["x"], rows["y"], rows["z"] = cloud.centers.T
    rows["red"], rows["green"], rows["blue"] = cloud.colors.T
    rows["label"], rows["confidence"] = cloud.labels, cloud.confidence
    if cloud.normals is not None:
        rows["nx"], rows["ny"], rows["nz"] = cloud.normals.T
    header = ["ply", "format binary_little_endian 1.0", "comment semmap map (label 65535 = no class)",
              f"comment resolution {cloud.resolution!r}", f"element vertex {len(cloud)}"]
    header += [f"property {_PLY_TYPES[t]} {name}" for name, t in fields] + ["end_header"]
    data = ("\n".join(header) + "\n").encode("ascii") + rows.tobytes()
    write_atomic(path, lambda f: f.write(data))
    return Path(path).stat().st_size


#: The vertex of a plain coloured point cloud (PCL's / Open3D's dense cloud): 15 bytes per point.
_COLOURED = [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1")]


def write_colored_cloud_ply(path: str | Path, points: np.ndarray, colors: np.ndarray, *, comment: str = "") -> int:
    """Write (N, 3) points and (N, 3) uint8 colours as a binary little-endian PLY (``x y z`` float32, ``red green
    blue`` uchar: the dense coloured cloud other tools write) atomically; returns the file size in bytes."""
    points, colors = np.asarray(points), np.asarray(colors)
    if points.ndim != 2 or points.shape[1] != 3 or colors.shape != points.shape:
        raise FormatError(f"{path}: a coloured cloud needs (N, 3) points and colours, got {points.shape} and "
                          f"{colors.shape}")
    rows = np.empty(len(points), dtype=_COLOURED)
    rows["x"], rows["y"], rows["z"] = points.T
    rows["red"], rows["green"], rows["blue"] = colors.T
    header = ["ply", "format binary_little_endian 1.0", *([f"comment {comment}"] if comment else []),
              f"element vertex {len(rows)}"]
    header += [f"property {_PLY_TYPES[t]} {name}" for name, t in _COLOURED] + ["end_header"]
    data = ("\n".join(header) + "\n").encode("ascii") + rows.tobytes()
    write_atomic(path, lambda f: f.write(data))
    return Path(path).stat().st_size


#: The header must end within this many bytes (semmap writes a few hundred).
MAX_PLY_HEADER = 64 * 1024


def read_ply(path: str | Path) -> MapCloud:
    """Read a PLY written by :func:`write_ply` back into a :class:`MapCloud`."""
    import mmap

    from semmap.files.safe import regular_file_size

    path = Path(path)
    if regular_file_size(path, what="PLY file") == 0:
        raise FormatError(f"{path}: file is empty")
    try:  # memory-mapped: a huge file is checked against its header before its vertices are touched
        with open(path, "rb") as f:
            raw = mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ)
    except (OSError, ValueError) as exc:
        raise FormatError(f"{path}: cannot read ({getattr(exc, 'strerror', None) or exc})") from None
    end = raw.find(b"end_header\n", 0, MAX_PLY_HEADER)
    if raw[:4] != b"ply\n" or end < 0:
        raise FormatError(f"{path}: not a PLY file (no 'ply' / 'end_header')")
    lines = raw[:end].decode("ascii", "replace").splitlines()
    if "format binary_little_endian 1.0" not in lines:
        raise FormatError(f"{path}: only binary little-endian PLY written by semmap is supported")
    try:
        n = next(int(line.split()[2]) for line in lines if line.startswith("element vertex"))
        resolution = next((float(line.split()[2]) for line in lines if line.startswith("comment resolution")), 0.0)
    except (StopIteration, IndexError, ValueError):
        raise FormatError(f"{path}: malformed PLY header") from None
    try:
        names = [line.split()[2] for line in lines if line.startswith("property")]
    except IndexError:
        raise FormatError(f"{path}: malformed PLY property line") from None
    fields = _BASE + (_NORMALS if "nx" in names else [])
    if names != [name for name, _ in fields]:
        raise FormatError(f"{path}: unexpected vertex properties {names}")
    start = end + len(b"end_header\n")
    body = len(raw) - start
    dtype = np.dtype(fields)
    if n < 0 or body != n * dtype.itemsize:
        raise FormatError(f"{path}: truncated PLY ({body} bytes of vertex data, expected {n * dtype.itemsize})")
    if any(line.startswith("comment resolution") for line in lines):
        check_file_resolution(resolution, path)
    rows = np.frombuffer(raw, dtype, count=n, offset=start).copy()
    _check_values(path, rows)
    normals = np.stack([rows["nx"], rows["ny"], rows["nz"]], 1).astype(np.float32) if "nx" in names else None
    return MapCloud(np.stack([rows["x"], rows["y"], rows["z"]], 1).astype(np.float64),
                    np.stack([rows["red"], rows["green"], rows["blue"]], 1).astype(np.uint8),
                    rows["label"].astype(np.uint16), rows["confidence"].astype(np.float32), resolution, normals)


def _check_values(path: Path, rows: np.ndarray) -> None:
    """Finite coordinates, normals and confidences in [0, 1]: a damaged file is refused naming it, never drawn."""
    names = [name for name in ("x", "y", "z", "nx", "ny", "nz") if name in rows.dtype.names]
    bad = sum(int((~np.isfinite(rows[name])).sum()) for name in names)
    if bad:
        raise FormatError(f"{path}: {bad:,} non-finite (NaN or infinite) coordinates or normals")
    conf = rows["confidence"]
    if conf.size and not (np.isfinite(conf).all() and conf.min() >= 0 and conf.max() <= 1.001):
        raise FormatError(f"{path}: confidences outside [0, 1] (or NaN)")
