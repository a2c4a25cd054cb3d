"""Reading files handed over by someone else: only regular files, and sizes checked before anything is read.

A device (``/dev/zero``), a FIFO or a socket named like a data file would make a plain ``read`` hang or never end;
a huge (or sparse) file would be read whole into memory. Readers call these helpers first, so every such file is
one clear error naming it, and memory stays bounded by the limits below.
"""

from __future__ import annotations

import os
import stat
from collections.abc import Callable
from pathlib import Path

import numpy as np

from semmap.errors import FormatError

#: Largest text file (trajectory, file list, pose, intrinsics, JSON) a reader accepts.
MAX_TEXT_BYTES = 64 * 2**20
#: Largest single image file (colour, depth or label) a reader accepts.
MAX_IMAGE_BYTES = 128 * 2**20
#: Pixels OpenCV may allocate for one decoded image (64 Mpx: 8192 x 8192), instead of its default 1 Gpx.
MAX_IMAGE_PIXELS = 2**26

ErrorFactory = Callable[[str], Exception]


def _format_error(path: str | Path) -> ErrorFactory:
    return lambda reason: FormatError(f"{path}: {reason}")


def regular_file_size(path: str | Path, *, what: str = "file", error: ErrorFactory | None = None) -> int:
    """Size in bytes of ``path`` if it is an existing regular file; else ``error(reason)`` (a :class:`FormatError`
    naming the file by default). Never opens the file, so a FIFO cannot block."""
    error = error or _format_error(path)
    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise error("file is missing" if what in ("file", "image file") else f"{what} does not exist") from None
    except OSError as exc:
        raise error(f"cannot read {what}: {exc.strerror or exc}") from None
    except ValueError as exc:  # a name with a NUL byte, e.g. from a damaged file list
        raise error(f"invalid {what} name ({exc})") from None
    if stat.S_ISDIR(st.st_mode):
        raise error(f"is a folder, expected a {what}")
    if not stat.S_ISREG(st.st_mode):
        raise error(f"is a {_special_kind(st.st_mode)}, not a regular file ({what} expected); refusing to read it")
    return int(st.st_size)


def _special_kind(mode: int) -> str:
    return "FIFO" if stat.S_ISFIFO(mode) else "device" if stat.S_ISCHR(mode) or stat.S_ISBLK(mode) else \
        "socket" if stat.S_ISSOCK(mode) else "special file"


def path_kind(path: str | Path) -> str:
    """What lies at ``path``, for a message: ``does not exist``, ``is a folder``, ``is a FIFO``, ``is a device``,
    ``is a regular file`` ... (never opens it)."""
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError:
        return "does not exist"
    except (OSError, ValueError) as exc:
        return f"cannot be read ({getattr(exc, 'strerror', None) or exc})"
    if stat.S_ISDIR(mode):
        return "is a folder"
    return "is a regular file" if stat.S_ISREG(mode) else f"is a {_special_kind(mode)}"


def read_bytes_limited(path: str | Path, max_bytes: int, *, what: str = "file",
                       error: ErrorFactory | None = None) -> bytes:
    """The bytes of a regular file of at most ``max_bytes`` (checked before reading, and while reading)."""
    error = error or _format_error(path)
    size = regular_file_size(path, what=what, error=error)
    if size > max_bytes:
        raise error(f"{what} is {size:,} bytes, more than the {max_bytes:,} accepted")
    try:
        with open(path, "rb") as f:
            data = f.read(max_bytes + 1)
    except OSError as exc:
        raise error(f"cannot read {what}: {exc.strerror or exc}") from None
    if len(data) > max_bytes:
        raise error(f"{what} grew beyond {max_bytes:,} bytes while being read")
    return data


def read_text_limited(path: str | Path, max_bytes: int = MAX_TEXT_BYTES, *, what: str = "file",
                      error: ErrorFactory | None = None) -> str:
    """UTF-8 text of a regular file of at most ``max_bytes``."""
    error = error or _format_error(path)
    data = read_bytes_limited(path, max_bytes, what=what, error=error)
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise error(f"{what} is not UTF-8 text (byte {exc.start}: {data[exc.start:exc.start + 1]!r})") from None


def limit_opencv() -> None:
    """Cap OpenCV's image decoder and silence its own warnings (semmap reports bad images itself).

    Must run before ``cv2`` decodes its first image: the pixel limit is read once."""
    os.environ.setdefault("OPENCV_IO_MAX_IMAGE_PIXELS", str(MAX_IMAGE_PIXELS))
    os.environ.setdefault("OPENCV_LOG_LEVEL", "ERROR")


def read_npy(f, available: int, *, what: str = "array", error: ErrorFactory) -> np.ndarray:
    """One ``.npy`` array from the open binary file ``f`` holding ``available`` bytes: its header (version, dtype,
    shape) is checked against those bytes before any data is read, so a header claiming 10^12 elements is refused
    without allocating them. Object arrays (pickles) are refused."""
    fmt = np.lib.format
    try:
        version = fmt.read_magic(f)
        read_header = {(1, 0): fmt.read_array_header_1_0, (2, 0): fmt.read_array_header_2_0,
                       (3, 0): fmt.read_array_header_2_0}.get(version)
        if read_header is None:
            raise error(f"{what} has unsupported .npy version {version}")
        shape, fortran, dtype = read_header(f, max_header_size=10_000)
    except ValueError as exc:
        raise error(f"{what} is not a valid .npy array ({exc})") from None
    if dtype.hasobject:
        raise error(f"{what} holds Python objects; only numeric arrays are read")
    count = int(np.prod(shape, dtype=np.int64)) if shape else 1
    nbytes = count * dtype.itemsize
    if min(shape, default=0) < 0 or nbytes > available:
        raise error(f"{what} claims shape {shape} of {dtype} ({nbytes:,} bytes), but only {available:,} bytes follow")
    data = f.read(nbytes)
    if len(data) != nbytes:
        raise error(f"{what} holds {len(data):,} bytes, its header says {nbytes:,}")
    return np.frombuffer(data, dtype).reshape(shape, order="F" if fortran else "C").copy()


def read_npz_members(path: str | Path, names: list[str] | None = None, *, what: str = "array file",
                     max_expansion: int = 100, min_budget: int = 64 * 2**20,
                     error: ErrorFactory | None = None) -> dict[str, np.ndarray]:
    """Arrays of a ``.npz`` (all, or ``names``), refusing zip bombs: the members' declared sizes must fit
    ``max(min_budget, max_expansion x file size)`` before anything is decompressed."""
    import zipfile
    import zlib

    error = error or _format_error(path)
    file_size = regular_file_size(path, what=what, error=error)
    try:
        with zipfile.ZipFile(path) as z:
            members = {info.filename.removesuffix(".npy"): info for info in z.infolist()}
            wanted = list(members) if names is None else names
            missing = [n for n in wanted if n not in members]
            if missing:
                raise error(f"{what} lacks {missing} (has {sorted(members)})")
            declared = sum(members[n].file_size for n in wanted)
            budget = max(min_budget, max_expansion * file_size)
            if declared > budget:
                raise error(f"its arrays would expand to {declared:,} bytes from a {file_size:,}-byte file (more "
                            f"than {max_expansion}x); refusing a possible zip bomb")
            out = {}
            for n in wanted:
                with z.open(members[n]) as f:
                    out[n] = read_npy(f, members[n].file_size, what=f"array {n!r}", error=error)
                    if f.read(1):
                        raise error(f"array {n!r} has bytes after its data")
            return out
    except (zipfile.BadZipFile, zipfile.LargeZipFile, EOFError, OSError, NotImplementedError, RuntimeError,
            ValueError, zlib.error) as exc:
        raise error(f"corrupt or truncated {what} ({type(exc).__name__}: {exc})") from None


def json_from_bytes(path: str | Path, raw: bytes, *, what: str = "header"):
    """The JSON value stored in ``raw`` (a file's header), or a FormatError naming ``path`` and ``what``."""
    import json

    try:
        return json.loads(raw.decode("utf-8"))
    except ValueError as exc:  # (UnicodeDecodeError and JSONDecodeError are ValueErrors)
        raise FormatError(f"{path}: {what} is not JSON ({exc})") from None
