"""OctoMap files: ``.bt`` (binary OcTree, occupied / free only) and ``.ot`` (full OcTree or ColorOcTree).

Layouts, as the OctoMap library reads and writes them:

- header: a first line starting ``# Octomap OcTree``, optional ``#`` comment lines, then ``id <type>``,
  ``size <nodes>``, ``res <metres>`` and ``data``, each on its own line; binary data follows;
- ``.ot``: every node in pre-order: float32 log-odds, for ColorOcTree 3 bytes r, g, b, then one byte with
  bit i set when child i exists;
- ``.bt``: every inner node in pre-order: two bytes holding 2 bits per child (children 0-3, then 4-7):
  ``01`` (low bit) = free leaf, ``10`` = occupied leaf, ``11`` = inner node, ``00`` = unknown.
  Leaves read from a ``.bt`` get the clamping log-odds, as in OctoMap.
"""

from __future__ import annotations

import contextlib
import re
from dataclasses import dataclass
from pathlib import Path

import numba as nb
import numpy as np

from semmap.errors import FormatError
from semmap.files.atomic import write_atomic
from semmap.keys import TREE_DEPTH
from semmap.limits import check_file_resolution
from semmap.maps.octree_tree import OctreeNodes, morton_decode

OT_MAGIC = "# Octomap OcTree file"
BT_MAGIC = "# Octomap OcTree binary file"
SUPPORTED_OT_TYPES = ("OcTree", "ColorOcTree")
_NODE_COLOR = np.dtype([("v", "<f4"), ("r", "u1"), ("g", "u1"), ("b", "u1"), ("m", "u1")])
_NODE_PLAIN = np.dtype([("v", "<f4"), ("m", "u1")])
_MAX_HEADER_LINES = 64
#: Longest header line read (OctoMap's are under 40 bytes): a file without line breaks is not scanned to its end.
_MAX_HEADER_LINE = 1024
#: Bytes of one node record in ``.ot`` data: float32 log-odds (+ RGB for ColorOcTree) + child mask.
_OT_RECORD = {"OcTree": 5, "ColorOcTree": 8}


def _header(magic: str, tree_type: str, size: int, resolution: float) -> bytes:
    comment = "# (written by semmap; OctoMap reads everything after the 'data' line as binary)"
    return f"{magic}\n{comment}\nid {tree_type}\nsize {size}\nres {float(resolution)!r}\ndata\n".encode("ascii")


def encode_ot(nodes: OctreeNodes, resolution: float, *, color: bool = True) -> bytes:
    """Bytes of an ``.ot`` file (ColorOcTree when ``color``, plain OcTree otherwise)."""
    rec = np.empty(len(nodes), _NODE_COLOR if color else _NODE_PLAIN)
    rec["v"] = nodes.values
    rec["m"] = nodes.child_masks
    if color:
        rec["r"], rec["g"], rec["b"] = nodes.colors[:, 0], nodes.colors[:, 1], nodes.colors[:, 2]
    return _header(OT_MAGIC, "ColorOcTree" if color else "OcTree", len(nodes), resolution) + rec.tobytes()


@nb.njit(cache=True)
def _bt_words(codes: np.ndarray, depths: np.ndarray, values: np.ndarray, masks: np.ndarray,
              threshold: np.float32) -> np.ndarray:
    """Two-byte child-state words of the inner nodes, in pre-order (children follow their parent)."""
    n = codes.shape[0]
    words = np.zeros(n, np.uint16)
    stack = np.empty(TREE_DEPTH + 2, np.int64)  # index of the open ancestor at each depth
    for i in range(n):
        d = depths[i]
        stack[d] = i
        if d > 0:
            parent = stack[d - 1]
            child = codes[i] & 7
            if masks[i] != 0:
                kind = 3
            elif values[i] >= threshold:
                kind = 2
            else:
                kind = 1
            words[parent] |= np.uint16(kind << (2 * child))
    return words


def encode_bt(nodes: OctreeNodes, resolution: float, occupancy_threshold_log: float = 0.0) -> bytes:
    """Bytes of a ``.bt`` file: the occupied / free state of every leaf of ``nodes``."""
    if len(nodes) == 0:
        return _header(BT_MAGIC, "OcTree", 0, resolution)
    words = _bt_words(nodes.codes, nodes.depths, nodes.values, nodes.child_masks,
                      np.float32(occupancy_threshold_log))
    inner = nodes.child_masks != 0
    w = words[inner]
    data = np.empty((w.shape[0], 2), np.uint8)
    data[:, 0] = w & 0xFF
    data[:, 1] = w >> 8
    if not inner[0]:  # a root that is itself a leaf: OctoMap writes its (empty) child bits
        data = np.zeros((1, 2), np.uint8)
    return _header(BT_MAGIC, "OcTree", len(nodes), resolution) + data.tobytes()


def write_ot(path: str | Path, nodes: OctreeNodes, resolution: float, *, color: bool = True) -> int:
    """Write an ``.ot`` file atomically; returns its size in bytes."""
    data = encode_ot(nodes, resolution, color=color)
    write_atomic(path, lambda f: f.write(data))
    return len(data)


def write_bt(path: str | Path, nodes: OctreeNodes, resolution: float, occupancy_threshold_log: float = 0.0) -> int:
    """Write a ``.bt`` file atomically; returns its size in bytes."""
    data = encode_bt(nodes, resolution, occupancy_threshold_log)
    write_atomic(path, lambda f: f.write(data))
    return len(data)


# ----------------------------------------------------------------------------------------------------- reading
@dataclass(frozen=True)
class OctreeLeaves:
    """Leaves of an OctoMap file: Morton prefix and depth (a leaf above depth 16 covers 8^(16-d) cells)."""

    tree_type: str
    resolution: float
    num_nodes: int
    codes: np.ndarray  # (L,) int64 Morton prefix at the leaf's depth
    depths: np.ndarray  # (L,) uint8
    values: np.ndarray  # (L,) float32 log-odds
    colors: np.ndarray | None  # (L, 3) uint8 for ColorOcTree

    def __len__(self) -> int:
        return int(self.codes.shape[0])

    def occupied(self, threshold_log: float = 0.0) -> np.ndarray:
        return self.values >= np.float32(threshold_log)

    def finest_count(self) -> int:
        """Number of finest-level cells the leaves cover."""
        return int((8 ** (TREE_DEPTH - self.depths.astype(np.int64))).sum())

    def expand(self, max_cells: int = 50_000_000) -> tuple[np.ndarray, np.ndarray]:
        """Finest-level keys (M, 3) and the index of the leaf each comes from (pruned leaves expanded)."""
        total = self.finest_count()
        if total > max_cells:
            raise FormatError(f"expanding this map gives {total} cells (limit {max_cells})")
        return _expand(self.codes, self.depths, total)


@nb.njit(cache=True)
def _expand(codes: np.ndarray, depths: np.ndarray, total: int):
    full = np.empty(total, np.int64)
    src = np.empty(total, np.int64)
    j = 0
    for i in range(codes.shape[0]):
        shift = 3 * (TREE_DEPTH - np.int64(depths[i]))
        base = codes[i] << shift
        for c in range(np.int64(1) << shift):
            full[j] = base + c
            src[j] = i
            j += 1
    return morton_decode(full), src


def _parse_header(data: bytes, path: str) -> tuple[str, str, int, float, int]:
    """(magic line, tree type, size, resolution, offset of the binary data)."""
    pos = 0
    lines: list[str] = []
    while len(lines) < _MAX_HEADER_LINES:
        end = data.find(b"\n", pos, pos + _MAX_HEADER_LINE)
        if end < 0:
            if not lines and not bytes(data[:len(OT_MAGIC)]).startswith(b"# Octomap"):
                raise FormatError(f"{path}: not an OctoMap file (first bytes {bytes(data[:16])!r})")
            raise FormatError(f"{path}: header ends before the 'data' line (file truncated?)")
        try:
            line = data[pos:end].decode("ascii").strip()
        except UnicodeDecodeError:
            raise FormatError(f"{path}: header contains binary data before the 'data' line") from None
        pos = end + 1
        lines.append(line)
        if line == "data":
            break
    else:
        raise FormatError(f"{path}: no 'data' line in the first {_MAX_HEADER_LINES} header lines")
    if not lines or not lines[0].startswith("# Octomap OcTree"):
        raise FormatError(f"{path}: not an OctoMap file (first line {lines[0][:40] if lines else ''!r})")
    fields: dict[str, str] = {}
    for line in lines[1:-1]:
        if not line or line.startswith("#"):
            continue
        m = re.fullmatch(r"(\w+)\s+(\S+)", line)
        if not m:
            raise FormatError(f"{path}: malformed header line {line!r}")
        fields[m.group(1)] = m.group(2)
    try:
        tree_type = fields.get("id", "OcTree")
        size = int(fields["size"])
        res = float(fields["res"])
    except KeyError as exc:
        raise FormatError(f"{path}: header lacks the {exc.args[0]!r} line") from None
    except ValueError as exc:
        raise FormatError(f"{path}: bad number in header: {exc}") from None
    if size < 0 or not (res > 0 and np.isfinite(res)):
        raise FormatError(f"{path}: bad size {size} or resolution {res} in header")
    check_file_resolution(res, path)
    return lines[0], tree_type, size, res, pos


@nb.njit(cache=True)
def _read_ot_nodes(buf: np.ndarray, pos: int, record: int, color: bool, max_nodes: int):
    """Walk ``.ot`` node records; returns (status, nodes read, end offset, leaf codes, depths, values, colours).
    status: 0 ok, 1 truncated, 2 too deep, 3 more nodes than the header says."""
    n = buf.shape[0]
    codes = np.empty(max_nodes, np.int64)
    depths = np.empty(max_nodes, np.uint8)
    values = np.empty(max_nodes, np.float32)
    colors = np.empty((max_nodes, 3), np.uint8)
    st_code = np.empty(TREE_DEPTH + 1, np.int64)
    st_mask = np.empty(TREE_DEPTH + 1, np.int64)
    nl = 0
    read = 0
    top = -1
    code = np.int64(0)
    depth = 0
    while True:
        if read >= max_nodes:
            return 3, read, pos, codes[:nl], depths[:nl], values[:nl], colors[:nl]
        if pos + record > n:
            return 1, read, pos, codes[:nl], depths[:nl], values[:nl], colors[:nl]
        v = buf[pos:pos + 4].copy().view(np.float32)[0]
        mask = np.int64(buf[pos + record - 1])
        read += 1
        if mask == 0:
            codes[nl] = code
            depths[nl] = depth
            values[nl] = v
            if color:
                colors[nl, 0] = buf[pos + 4]
                colors[nl, 1] = buf[pos + 5]
                colors[nl, 2] = buf[pos + 6]
            nl += 1
        else:
            if depth >= TREE_DEPTH:
                return 2, read, pos, codes[:nl], depths[:nl], values[:nl], colors[:nl]
            top += 1
            st_code[top] = code
            st_mask[top] = mask
        pos += record
        # next node: the lowest remaining child of the deepest open node
        while top >= 0 and st_mask[top] == 0:
            top -= 1
        if top < 0:
            return 0, read, pos, codes[:nl], depths[:nl], values[:nl], colors[:nl]
        m = st_mask[top]
        i = 0
        while (m >> i) & 1 == 0:
            i += 1
        st_mask[top] = m & ~(np.int64(1) << i)
        code = (st_code[top] << 3) | i
        depth = top + 1


@nb.njit(cache=True)
def _read_bt_nodes(buf: np.ndarray, pos: int, max_inner: int, occ_value: np.float32, free_value: np.float32):
    """Walk ``.bt`` inner-node words; returns (status, inner nodes read, end offset, leaf codes, depths, values).
    status: 0 ok, 1 truncated, 2 too deep, 3 more nodes than the header says."""
    n = buf.shape[0]
    cap = 8 * max_inner + 8
    codes = np.empty(cap, np.int64)
    depths = np.empty(cap, np.uint8)
    values = np.empty(cap, np.float32)
    st_code = np.empty(TREE_DEPTH + 1, np.int64)
    st_word = np.empty(TREE_DEPTH + 1, np.int64)
    st_next = np.empty(TREE_DEPTH + 1, np.int64)
    nl = 0
    read = 0
    if pos + 2 > n:
        return 1, 0, pos, codes[:0], depths[:0], values[:0]
    st_code[0] = 0
    st_word[0] = np.int64(buf[pos]) | (np.int64(buf[pos + 1]) << 8)
    st_next[0] = 0
    pos += 2
    read = 1
    top = 0
    while top >= 0:
        i = st_next[top]
        if i >= 8:
            top -= 1
            continue
        st_next[top] = i + 1
        kind = (st_word[top] >> (2 * i)) & 3
        if kind == 0:
            continue
        code = (st_code[top] << 3) | i
        if kind == 3:
            if top + 1 >= TREE_DEPTH:
                return 2, read, pos, codes[:nl], depths[:nl], values[:nl]
            if read >= max_inner:
                return 3, read, pos, codes[:nl], depths[:nl], values[:nl]
            if pos + 2 > n:
                return 1, read, pos, codes[:nl], depths[:nl], values[:nl]
            top += 1
            st_code[top] = code
            st_word[top] = np.int64(buf[pos]) | (np.int64(buf[pos + 1]) << 8)
            st_next[top] = 0
            pos += 2
            read += 1
        else:
            codes[nl] = code
            depths[nl] = top + 1
            values[nl] = occ_value if kind == 2 else free_value
            nl += 1
    return 0, read, pos, codes[:nl], depths[:nl], values[:nl]


_STATUS = {1: "data is truncated", 2: "tree is deeper than 16 levels", 3: "data holds more nodes than 'size' says"}


def decode_octomap(data: bytes, path: str = "<bytes>", *, clamp_min_log: float = -2.000028,
                   clamp_max_log: float = 3.5110307) -> OctreeLeaves:
    """Parse ``.ot`` or ``.bt`` bytes into leaves; :class:`FormatError` on anything malformed."""
    magic, tree_type, size, res, pos = _parse_header(data, path)
    binary = magic.startswith(BT_MAGIC)
    _check_size_against_length(path, size, len(data) - pos, binary, tree_type)
    buf = np.frombuffer(data, np.uint8)
    if size == 0:
        empty = np.zeros(0, np.int64)
        return OctreeLeaves(tree_type, res, 0, empty, empty.astype(np.uint8), empty.astype(np.float32), None)
    if binary:
        if tree_type != "OcTree":
            raise FormatError(f"{path}: binary files hold an OcTree, header says {tree_type!r}")
        status, read, end, codes, depths, values = _read_bt_nodes(
            buf, pos, size, np.float32(clamp_max_log), np.float32(clamp_min_log))
        colors = None
        nodes = read + len(codes)
    else:
        if tree_type not in SUPPORTED_OT_TYPES:
            raise FormatError(f"{path}: unsupported tree type {tree_type!r} (supported: {SUPPORTED_OT_TYPES})")
        color = tree_type == "ColorOcTree"
        status, nodes, end, codes, depths, values, colors = _read_ot_nodes(
            buf, pos, 8 if color else 5, color, size)
        if not color:
            colors = None
    if status:
        raise FormatError(f"{path}: {_STATUS[status]} (header size {size}, read {nodes} nodes)")
    if nodes != size:
        raise FormatError(f"{path}: header says {size} nodes but the data holds {nodes}")
    if end != len(data):
        raise FormatError(f"{path}: {len(data) - end} unexpected bytes after the tree data")
    if not np.isfinite(values).all():
        bad = int((~np.isfinite(values)).sum())
        raise FormatError(f"{path}: {bad} leaves have non-finite (NaN or infinite) log-odds")
    return OctreeLeaves(tree_type, res, nodes, codes.copy(), depths.copy(), values.copy(),
                        None if colors is None else colors.copy())


def _check_size_against_length(path: str, size: int, data_bytes: int, binary: bool, tree_type: str) -> None:
    """The node count the header claims must fit in the bytes the file has, before anything is allocated for it:
    an ``.ot`` stores one fixed-size record per node, a ``.bt`` two bytes per inner node and at most 8 leaves each."""
    if binary:
        most = 9 * (data_bytes // 2) + 1
        need = "2 bytes per inner node"
    else:
        record = _OT_RECORD.get(tree_type)
        if record is None:
            return  # an unsupported type is refused by the caller, with its name
        most = data_bytes // record
        need = f"{record} bytes per node"
    if size > most:
        raise FormatError(f"{path}: header says {size:,} nodes, but the {data_bytes:,} bytes of tree data hold at "
                          f"most {most:,} ({need})")


def read_octomap(path: str | Path) -> OctreeLeaves:
    """Read an ``.ot`` or ``.bt`` file (by content, not by extension).

    The file is memory-mapped: only the pages the parser reaches are read, so a huge or sparse file that is not a
    valid tree costs its header, not its length; devices and FIFOs are refused without being opened."""
    import mmap

    from semmap.files.safe import regular_file_size

    size = regular_file_size(path, what="OctoMap file")
    if size == 0:
        raise FormatError(f"{path}: file is empty")
    try:
        with open(path, "rb") as f:
            data = mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ)
    except (OSError, ValueError) as exc:
        raise FormatError(f"{path}: cannot read: {getattr(exc, 'strerror', None) or exc}") from None
    try:
        return decode_octomap(data, str(path))
    finally:
        with contextlib.suppress(BufferError):  # an error's traceback may still hold a view; GC closes it then
            data.close()

