"""ScanNet scans: the ``.sens`` stream (colour, depth, camera poses, calibration), with the filtered 2D labels
(``label-filt/<frame>.png``, ScanNet label ids) mapped to NYU-40 through ``scannetv2-labels.combined.tsv`` and
the filtered instances (``instance-filt/<frame>.png``).

The ``.sens`` layout (ScanNet's SensReader, ``sensorData.h``), little-endian: ``uint32`` version (4); ``uint64``
length and the sensor name; four 4x4 ``float32`` matrices (colour intrinsics, colour extrinsics, depth
intrinsics, depth extrinsics); ``int32`` colour compression (-1 unknown, 0 raw, 1 png, 2 jpeg) and depth
compression (-1 unknown, 0 raw ushort, 1 zlib ushort, 2 occi); ``uint32`` colour width, height, depth width, height;
``float32`` depth shift (stored units per metre, 1000); ``uint64`` frame count; then per frame a 4x4 ``float32``
camera-to-world pose, ``uint64`` colour and depth timestamps (microseconds), ``uint64`` colour and depth byte
counts and the two payloads. IMU records follow the frames and are not read.

Frames are given at the depth camera's size and intrinsics (colour resized onto it, labels by nearest neighbour),
as the ScanNet benchmarks do. Frames whose pose is invalid (ScanNet marks lost tracking with -inf) are skipped.
"""

from __future__ import annotations

import csv
import io
import struct
import zlib
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from semmap.datasets.base import LOG, FormatEntry, SequenceReader, UnreadableFileError, ensure_folder
from semmap.errors import DatasetError
from semmap.labels import NYU40_NAMES, nyu40_labels
from semmap.types import CameraIntrinsics, Frame, check_pose

SENS_VERSION = 4
LABEL_MAP_FILE = "scannetv2-labels.combined.tsv"
#: Largest payload of one frame accepted (a 1296x968 PNG is under 4 MB; anything far larger is not a frame).
MAX_FRAME_BYTES = 64 * 1024 * 1024
_HEADER_AFTER_NAME = struct.Struct("<64f2i4If Q")
_FRAME_HEADER = struct.Struct("<16f4Q")
COLOR_CODECS = {0: "raw", 1: "png", 2: "jpeg"}
DEPTH_CODECS = {0: "raw_ushort", 1: "zlib_ushort"}


@dataclass(frozen=True)
class SensHeader:
    """What a ``.sens`` file says about its cameras and how its frames are stored."""

    sensor: str
    color_intrinsics: np.ndarray  # (4, 4)
    depth_intrinsics: np.ndarray  # (4, 4)
    color_codec: int
    depth_codec: int
    color_size: tuple[int, int]  # width, height
    depth_size: tuple[int, int]
    depth_shift: float
    frames: int


@dataclass(frozen=True)
class _SensRef:
    """Where one frame lies in the stream."""

    index: int
    offset: int  # of the frame header
    color_bytes: int
    depth_bytes: int

    @property
    def name(self) -> str:
        return str(self.index)


def _fail(path: Path, reason: str) -> DatasetError:
    return DatasetError(f"{path}: {reason} (not a ScanNet .sens stream, or a truncated one)")


def read_sens_header(f, path: Path, file_size: int) -> tuple[SensHeader, int]:
    """The header and the offset of the first frame."""
    head = f.read(12)
    if len(head) < 12:
        raise _fail(path, "file ends inside the header")
    version, name_len = struct.unpack("<IQ", head)
    if version != SENS_VERSION:
        raise _fail(path, f"version {version}, expected {SENS_VERSION}")
    if name_len > 4096:
        raise _fail(path, f"sensor name of {name_len:,} bytes")
    name = f.read(name_len).decode("utf-8", errors="replace")
    rest = f.read(_HEADER_AFTER_NAME.size)
    if len(rest) < _HEADER_AFTER_NAME.size:
        raise _fail(path, "file ends inside the header")
    v = _HEADER_AFTER_NAME.unpack(rest)
    mats = np.array(v[:64], np.float64).reshape(4, 4, 4)
    color_codec, depth_codec = v[64], v[65]
    cw, ch, dw, dh = v[66:70]
    shift, frames = v[70], v[71]
    if depth_codec not in DEPTH_CODECS:
        raise DatasetError(f"{path}: depth compression {depth_codec} is not supported (raw or zlib ushort are)")
    if color_codec not in COLOR_CODECS:
        raise DatasetError(f"{path}: colour compression {color_codec} is not supported (raw, png or jpeg are)")
    if not (0 < dw <= 8192 and 0 < dh <= 8192 and 0 < cw <= 8192 and 0 < ch <= 8192):
        raise _fail(path, f"image sizes {cw}x{ch} / {dw}x{dh}")
    if not (np.isfinite(shift) and shift > 0):
        raise _fail(path, f"depth shift {shift}")
    start = 12 + name_len + _HEADER_AFTER_NAME.size
    if frames > (file_size - start) // _FRAME_HEADER.size:
        raise _fail(path, f"{frames:,} frames announced in {file_size:,} bytes")
    return SensHeader(name, mats[0], mats[2], color_codec, depth_codec, (cw, ch), (dw, dh), float(shift),
                      int(frames)), start


def index_frames(f, path: Path, header: SensHeader, start: int, file_size: int) -> list[_SensRef]:
    """Offsets of every frame (headers only: the payloads are skipped)."""
    refs, offset = [], start
    for i in range(header.frames):
        f.seek(offset)
        raw = f.read(_FRAME_HEADER.size)
        if len(raw) < _FRAME_HEADER.size:
            raise _fail(path, f"frame {i} of {header.frames} is cut off")
        *_, color_bytes, depth_bytes = _FRAME_HEADER.unpack(raw)
        if color_bytes > MAX_FRAME_BYTES or depth_bytes > MAX_FRAME_BYTES:
            raise _fail(path, f"frame {i} claims {color_bytes:,} + {depth_bytes:,} bytes")
        end = offset + _FRAME_HEADER.size + color_bytes + depth_bytes
        if end > file_size:
            raise _fail(path, f"frame {i} of {header.frames} is cut off")
        refs.append(_SensRef(i, offset, int(color_bytes), int(depth_bytes)))
        offset = end
    return refs


def _intrinsics(K: np.ndarray, size: tuple[int, int], path: Path) -> CameraIntrinsics:
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    if not (np.isfinite([fx, fy, cx, cy]).all() and fx > 0 and fy > 0):
        raise DatasetError(f"{path}: depth intrinsics are not a camera matrix ({K[:3, :3].tolist()})")
    return CameraIntrinsics(size[0], size[1], float(fx), float(fy), float(cx), float(cy))


def read_label_map(path: Path) -> np.ndarray:
    """ScanNet label id -> NYU-40 id lookup table from ``scannetv2-labels.combined.tsv`` (columns ``id``,
    ``nyu40id``; unlisted ids map to 0, unknown)."""
    text = path.read_text(encoding="utf-8", errors="replace")
    rows = list(csv.DictReader(io.StringIO(text), delimiter="\t"))
    if not rows or "id" not in rows[0] or "nyu40id" not in rows[0]:
        raise DatasetError(f"{path}: needs tab-separated columns 'id' and 'nyu40id'")
    pairs = []
    for r in rows:
        try:
            pairs.append((int(r["id"]), int(r["nyu40id"])))
        except (TypeError, ValueError):
            continue
    if not pairs:
        raise DatasetError(f"{path}: no row maps a label id to an NYU-40 id")
    top = max(i for i, _ in pairs)
    if top > 65535:
        raise DatasetError(f"{path}: label id {top} does not fit 16 bits")
    table = np.zeros(65536, np.uint16)
    for scannet_id, nyu in pairs:
        table[scannet_id] = nyu if 0 <= nyu < len(NYU40_NAMES) else 0
    return table


def _find_label_map(root: Path) -> Path | None:
    for where in (root, root.parent, root.parent.parent):
        if (where / LABEL_MAP_FILE).is_file():
            return where / LABEL_MAP_FILE
    return None


class ScanNetDataset(SequenceReader[_SensRef]):
    """One ScanNet scan folder (``<scan>.sens``, optional ``label-filt/`` and ``instance-filt/``)."""

    def __init__(self, root: str | Path, *, stride: int = 1, max_frames: int | None = None,
                 strict: bool = False) -> None:
        root = ensure_folder(root)
        streams = sorted(root.glob("*.sens"))
        if not streams:
            raise DatasetError(f"{root}: no .sens file (ScanNet scan folders hold <scan>.sens)")
        self.sens = streams[0]
        size = self.sens.stat().st_size
        with open(self.sens, "rb") as f:
            self.header, start = read_sens_header(f, self.sens, size)
            refs = index_frames(f, self.sens, self.header, start, size)
        cam = _intrinsics(self.header.depth_intrinsics, self.header.depth_size, self.sens)
        self._labels_dir = root / "label-filt" if (root / "label-filt").is_dir() else None
        self._instances_dir = root / "instance-filt" if (root / "instance-filt").is_dir() else None
        self._label_map = None
        if self._labels_dir is not None:
            found = _find_label_map(root)
            if found is None:
                LOG.warning("%s: label-filt/ holds ScanNet label ids but no %s was found beside the scan (or up to "
                            "two folders up); frames are read without labels", root, LABEL_MAP_FILE)
                self._labels_dir = None
            else:
                self._label_map = read_label_map(found)
        super().__init__(root, refs, stride=stride, max_frames=max_frames, intrinsics=cam,
                         label_set=nyu40_labels() if self._labels_dir is not None else None, strict=strict)
        self.depth_units = self.header.depth_shift

    def _payloads(self, ref: _SensRef) -> tuple[np.ndarray, int, bytes, bytes]:
        with open(self.sens, "rb") as f:
            f.seek(ref.offset)
            raw = f.read(_FRAME_HEADER.size + ref.color_bytes + ref.depth_bytes)
        values = _FRAME_HEADER.unpack(raw[:_FRAME_HEADER.size])
        pose = np.array(values[:16], np.float64).reshape(4, 4)
        color = raw[_FRAME_HEADER.size:_FRAME_HEADER.size + ref.color_bytes]
        return pose, int(values[16]), color, raw[_FRAME_HEADER.size + ref.color_bytes:]

    def _color(self, data: bytes, ref: _SensRef) -> np.ndarray:
        w, h = self.header.color_size
        if self.header.color_codec == 0:
            if len(data) != w * h * 3:
                raise UnreadableFileError(self.sens, f"frame {ref.index}: raw colour of {len(data)} bytes")
            rgb = np.frombuffer(data, np.uint8).reshape(h, w, 3)
        else:
            bgr = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
            if bgr is None:
                raise UnreadableFileError(self.sens, f"frame {ref.index}: colour image cannot be decoded")
            rgb = cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)
        cam = self._intrinsics
        if rgb.shape[:2] != (cam.height, cam.width):
            rgb = cv2.resize(rgb, (cam.width, cam.height), interpolation=cv2.INTER_AREA)
        return rgb

    def _depth(self, data: bytes, ref: _SensRef) -> np.ndarray:
        w, h = self.header.depth_size
        if self.header.depth_codec == 1:
            try:
                data = zlib.decompressobj().decompress(data, w * h * 2 + 1)
            except zlib.error as exc:
                raise UnreadableFileError(self.sens, f"frame {ref.index}: depth cannot be decompressed ({exc})") \
                    from None
        if len(data) != w * h * 2:
            raise UnreadableFileError(self.sens, f"frame {ref.index}: depth of {len(data)} bytes, expected {w * h * 2}")
        raw = np.frombuffer(data, "<u2").reshape(h, w)
        return raw.astype(np.float32) / np.float32(self.header.depth_shift)

    def _ids(self, folder: Path | None, ref: _SensRef, dtype) -> np.ndarray | None:
        if folder is None:
            return None
        path = folder / f"{ref.index}.png"
        if not path.is_file():
            return None
        ids = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if ids is None or ids.ndim != 2:
            raise UnreadableFileError(path, "label image must be a single-channel PNG")
        cam = self._intrinsics
        if ids.shape != (cam.height, cam.width):
            ids = cv2.resize(ids, (cam.width, cam.height), interpolation=cv2.INTER_NEAREST)
        return ids.astype(dtype)

    def _load(self, ref: _SensRef) -> Frame:
        pose, stamp, color, depth = self._payloads(ref)
        try:
            pose = check_pose(pose, f"{self.sens} frame {ref.index}")
        except DatasetError:
            raise UnreadableFileError(self.sens, f"frame {ref.index}: invalid camera pose (tracking lost)") from None
        labels = self._ids(self._labels_dir, ref, np.uint16)
        if labels is not None:
            labels = self._label_map[labels]
        return Frame(index=ref.index, timestamp=stamp * 1e-6 if stamp else ref.index / 30.0,
                     rgb=self._color(color, ref), depth=self._depth(depth, ref), intrinsics=self._intrinsics,
                     T_world_cam=pose, labels=labels, instances=self._ids(self._instances_dir, ref, np.int32),
                     name=f"frame-{ref.index:06d}")


def _open_scannet(root: Path, *, labels, raw_color: bool, ros: dict | None, **kwargs) -> ScanNetDataset:
    if labels is not None:
        raise DatasetError(f"{root}: a ScanNet scan brings its own labels (label-filt/); --labels is not used")
    return ScanNetDataset(root, **kwargs)


#: ScanNet's scan folder.
FORMAT = FormatEntry("scannet", _open_scannet, "ScanNet scan folder: <scan>.sens (+ label-filt/, instance-filt/, "
                     f"{LABEL_MAP_FILE})", detect=lambda root: next(root.glob("*.sens"), None) is not None,
                     looks_for="a *.sens stream (ScanNet)")
