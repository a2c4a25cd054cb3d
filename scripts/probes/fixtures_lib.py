"""Byte-level helpers for the probe fixtures (build_fixtures.py): broken copies of good files, crafted headers,
device nodes, FIFOs, sparse files and PNG bombs. Pure file manipulation; no semmap imports here."""

from __future__ import annotations

import hashlib
import io
import json
import os
import shutil
import stat
import struct
import zipfile
import zlib
from pathlib import Path

import numpy as np


def noise(name: str, n: int = 4096) -> bytes:
    """``n`` deterministic pseudo-random bytes seeded by ``name`` (garbage that is the same on every build)."""
    seed = int.from_bytes(hashlib.sha256(name.encode()).digest()[:8], "little")
    data = np.random.default_rng(seed).integers(0, 256, n, dtype=np.uint8).tobytes()
    return b"\x82" + data[1:] if data[:1].isascii() else data  # never valid UTF-8 text from its first bytes on


def write(path: Path, data: bytes | str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(data.encode() if isinstance(data, str) else data)


def truncated(src: Path, dst: Path, keep: int | float) -> None:
    """``dst`` = the first ``keep`` bytes of ``src`` (a fraction when ``keep`` < 1)."""
    data = src.read_bytes()
    n = int(len(data) * keep) if isinstance(keep, float) else keep
    write(dst, data[:n])


def char_device(path: Path, minor: int = 5) -> None:
    """A character device node (1, minor): 5 = /dev/zero, 3 = /dev/null; a symlink to it without CAP_MKNOD."""
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        os.mknod(path, stat.S_IFCHR | 0o666, os.makedev(1, minor))
    except PermissionError:
        os.symlink({5: "/dev/zero", 3: "/dev/null"}[minor], path)


def fifo(path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    os.mkfifo(path, 0o644)


def sparse(path: Path, size: int = 2**30) -> None:
    """A sparse file of ``size`` zero bytes (1 GiB by default) that takes no disk space."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as f:
        f.truncate(size)


def symlink_loop(path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    os.symlink(path.name, path)


def copytree(src: Path, dst: Path) -> None:
    shutil.copytree(src, dst, symlinks=True)


def png_bomb(path: Path, width: int = 50000, height: int = 50000, bit_depth: int = 16) -> None:
    """A grey PNG whose header claims ``width`` x ``height`` (GBs decoded) but whose data holds a few rows."""
    def chunk(kind: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body) & 0xFFFFFFFF)

    ihdr = struct.pack(">IIBBBBB", width, height, bit_depth, 0, 0, 0, 0)
    rows = zlib.compress(b"\0" * ((width * bit_depth // 8 + 1) * 4), 9)
    write(path, b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", rows) + chunk(b"IEND", b""))


# ------------------------------------------------------------------------------------------------ OctoMap files
def split_octomap(data: bytes) -> tuple[list[str], bytes]:
    """(header lines before 'data', tree bytes) of an .ot / .bt file."""
    head, sep, tree = data.partition(b"\ndata\n")
    assert sep, "not an OctoMap file"
    return head.decode().split("\n"), tree


def octomap_with(src: Path, dst: Path, *, tree: bytes | None = None, drop_data: bool = False, **fields: str) -> None:
    """A copy of OctoMap file ``src`` with header ``fields`` replaced (id=, size=, res=) and optionally other
    tree bytes or no 'data' line."""
    lines, data = split_octomap(src.read_bytes())
    out = []
    for line in lines:
        key = line.split(" ", 1)[0]
        out.append(f"{key} {fields[key]}" if key in fields else line)
    head = "\n".join(out).encode()
    write(dst, head + b"\n" if drop_data else head + b"\ndata\n" + (data if tree is None else tree))


# ------------------------------------------------------------------------------------------------ .semmap files
def read_semmap(path: Path) -> tuple[dict, dict[str, np.ndarray]]:
    """(header JSON, other arrays) of a .semmap zip (npz layout, header as a uint8 JSON array)."""
    arrays = dict(np.load(path, allow_pickle=False))
    header = json.loads(arrays.pop("header").tobytes())
    return header, arrays


def write_semmap(path: Path, header: object, arrays: dict[str, np.ndarray], *, with_header: bool = True) -> None:
    """A .semmap zip from a header (any JSON value) and arrays; object arrays are pickled (as a hostile file)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z:
        members = dict(arrays)
        if with_header:
            text = json.dumps(header).encode()
            members = {"header": np.frombuffer(text, dtype=np.uint8), **members}
        for name, arr in members.items():
            buf = io.BytesIO()
            np.lib.format.write_array(buf, np.asanyarray(arr), allow_pickle=True)
            z.writestr(f"{name}.npy", buf.getvalue())


def semmap_variant(src: Path, dst: Path, edit) -> None:
    """``dst`` = ``src`` with ``edit(header, arrays)`` applied (it may return a replacement header)."""
    header, arrays = read_semmap(src)
    new = edit(header, arrays)
    write_semmap(dst, header if new is None else new, arrays)


# ------------------------------------------------------------------------------------------------ PLY files
PLY_TYPES = {"float": "<f4", "double": "<f8", "uchar": "u1", "char": "i1", "ushort": "<u2", "short": "<i2",
             "uint": "<u4", "int": "<i4"}


def split_ply(data: bytes) -> tuple[list[str], bytes]:
    head, sep, body = data.partition(b"end_header\n")
    assert sep, "not a PLY file"
    return head.decode().strip().split("\n"), body


def ply_vertices(src: Path) -> tuple[list[str], np.ndarray]:
    """(header lines, structured vertex array) of a binary little-endian PLY."""
    lines, body = split_ply(src.read_bytes())
    props = [(p.split()[2], PLY_TYPES[p.split()[1]]) for p in lines if p.startswith("property ")]
    return lines, np.frombuffer(body, dtype=np.dtype(props)).copy()


def ply_from(lines: list[str], body: bytes) -> bytes:
    return ("\n".join(lines) + "\nend_header\n").encode() + body


def ply_header_edit(src: Path, dst: Path, edit) -> None:
    """``dst`` = ``src`` with its header lines passed through ``edit(lines) -> lines`` (body unchanged)."""
    lines, body = split_ply(src.read_bytes())
    write(dst, ply_from(edit(list(lines)), body))


def ply_xyz(dst: Path, xyz: np.ndarray) -> None:
    """A PLY with only x, y, z float properties (a point cloud semmap did not write)."""
    lines = ["ply", "format binary_little_endian 1.0", f"element vertex {len(xyz)}",
             "property float x", "property float y", "property float z"]
    write(dst, ply_from(lines, np.ascontiguousarray(xyz, dtype="<f4").tobytes()))
