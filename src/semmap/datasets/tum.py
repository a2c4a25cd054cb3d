"""TUM RGB-D benchmark sequences (``rgb.txt``, ``depth.txt``, optional ``groundtruth.txt``).

Also reads the per-frame ground truth our simulator writes next to them (``labels/``, ``instances/``,
``labelset.json``, ``camera.json``; see :mod:`semmap.io.tum_writer`).
"""

from __future__ import annotations

import json
import re
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from semmap.datasets.accelerometer import up_at
from semmap.datasets.base import (
    LOG,
    FormatEntry,
    SequenceReader,
    check_image_size,
    ensure_folder,
    image_size,
    read_color,
    read_depth,
)
from semmap.datasets.label_folder import LabelFolder, as_label_folder, choose_label_set
from semmap.errors import ConfigError, DatasetError, FormatError
from semmap.files.safe import read_text_limited
from semmap.io.trajectory import pose_at, read_tum, warn_repeated_stamps
from semmap.types import DEFAULT_INTRINSICS, CameraIntrinsics, Frame, check_pose

#: Factory calibrations of the three Kinects (fx, fy, cx, cy), picked by the sequence folder name.
FREIBURG_INTRINSICS = {
    "freiburg1": (517.3, 516.5, 318.6, 255.3),
    "freiburg2": (520.9, 521.0, 325.1, 249.7),
    "freiburg3": (535.4, 539.2, 320.1, 247.6),
}
CAMERA_FILE = "camera.json"


@dataclass(frozen=True)
class _TumRef:
    """One associated rgb/depth pair and its ground-truth pose."""

    index: int
    timestamp: float
    name: str
    rgb: Path
    depth: Path
    T_world_cam: np.ndarray | None
    up_cam: np.ndarray | None = None


class TumDataset(SequenceReader[_TumRef]):
    """TUM RGB-D sequence: rgb/depth associated by timestamp, pose interpolated from ``groundtruth.txt``.

    ``depth_scale`` is stored units per metre (5000 for TUM); ``labels_dir`` overrides a ``labels/`` folder
    in the root. Frames are named by the rgb file stem (``1305031102.175304``).
    """

    def __init__(
        self,
        root: str | Path,
        *,
        max_time_diff: float = 0.02,
        depth_scale: float = 5000.0,
        intrinsics: CameraIntrinsics | None = None,
        stride: int = 1,
        max_frames: int | None = None,
        labels_dir: str | Path | LabelFolder | None = None,
        strict: bool = False,
    ) -> None:
        root = ensure_folder(root)
        if not max_time_diff >= 0:
            raise ConfigError(f"max_time_diff must be >= 0 seconds, got {max_time_diff}")
        if not depth_scale > 0:
            raise ConfigError(f"depth_scale must be positive, got {depth_scale}")
        self._depth_scale = float(depth_scale)
        self.depth_units = self._depth_scale

        rgb, depth, pairs = _paired_lists(root, max_time_diff, stride, max_frames)
        if len(pairs) < len(rgb):
            LOG.info("%s: %d of %d colour frames have no depth frame within %.3f s",
                     root, len(rgb) - len(pairs), len(rgb), max_time_diff)
        gt_path = root / "groundtruth.txt"
        gt_stamps, gt_rows = (_read_groundtruth(gt_path, strict) if gt_path.is_file()
                              else (np.empty(0), np.empty((0, 7))))

        gravity = read_accelerometer(root / ACCELEROMETER) if (root / ACCELEROMETER).is_file() else None
        refs = []
        for index, (i, j) in enumerate(pairs):
            stamp, rgb_rel = rgb[i]
            rgb_path = root / rgb_rel
            pose = pose_at(gt_stamps, gt_rows, stamp, max_time_diff)
            if pose is not None:
                check_pose(pose, f"{gt_path} at t={stamp:.6f}")
            up = None if gravity is None else up_at(*gravity, stamp)
            refs.append(_TumRef(index, stamp, rgb_path.stem, rgb_path, root / depth[j][1], pose, up))

        if intrinsics is None:
            intrinsics = _find_intrinsics(root, [r.rgb for r in refs])
        self._labels = as_label_folder(labels_dir)
        if self._labels is None and (root / "labels").is_dir():
            self._labels = LabelFolder(root / "labels")
        self._instances = (LabelFolder(root / "instances", kind="instance")
                           if (root / "instances").is_dir() else None)
        super().__init__(root, refs, stride=stride, max_frames=max_frames, intrinsics=intrinsics,
                         label_set=choose_label_set(self._labels, root), strict=strict)

    def _load(self, ref: _TumRef) -> Frame:
        cam = self._intrinsics
        rgb = read_color(ref.rgb)
        check_image_size(rgb, cam, ref.rgb, "colour")
        depth = read_depth(ref.depth, self._depth_scale)
        check_image_size(depth, cam, ref.depth, "depth")
        labels = self._labels.read(ref.name, cam, self._classes()) if self._labels else None
        instances = self._instances.read(ref.name, cam) if self._instances else None
        return Frame(
            index=ref.index,
            timestamp=ref.timestamp,
            rgb=rgb,
            depth=depth,
            intrinsics=cam,
            T_world_cam=ref.T_world_cam,
            labels=labels,
            instances=None if instances is None else instances.astype(np.int32),
            name=ref.name,
            up_cam=ref.up_cam,
        )


# --------------------------------------------------------------------------------------------------
# Text files
# --------------------------------------------------------------------------------------------------
#: Colour rows read beyond the ones ``max_frames`` needs, so that pairing them with depth frames ends as with the
#: whole file (a depth frame goes to the closest colour frame, which may lie a little further down the list).
READ_MARGIN = 64


def _paired_lists(root: Path, max_time_diff: float, stride: int, max_frames: int | None):
    """``rgb.txt`` and ``depth.txt`` rows (a repeated timestamp: its first row only, as the warning says) and their
    pairs; with ``max_frames`` only the colour rows it needs are read (a huge list costs what is used)."""
    counted = isinstance(max_frames, int) and isinstance(stride, int) and max_frames >= 1 and stride >= 1
    needed = int(stride) * (int(max_frames) - 1) + 1 if counted else None
    limit = None if needed is None else needed + READ_MARGIN
    depth = _first_per_stamp(root / "depth.txt", read_file_list(root / "depth.txt"))
    while True:
        rgb_rows = read_file_list(root / "rgb.txt", limit=limit)
        rgb = _first_per_stamp(root / "rgb.txt", rgb_rows)
        pairs = associate([t for t, _ in rgb], [t for t, _ in depth], max_time_diff)
        if limit is None or len(rgb_rows) < limit or len(pairs) >= needed:
            return rgb, depth, pairs
        limit *= 8  # too few colour rows had a depth frame: read further


def _first_per_stamp(path: Path, rows: list[tuple[float, str]]) -> list[tuple[float, str]]:
    """``rows`` without those repeating an earlier row's timestamp (warned, naming ``path``): two frames of one
    time cannot both be posed, paired or written to a trajectory."""
    warn_repeated_stamps(path, [t for t, _ in rows])
    seen: set[float] = set()
    out = []
    for row in rows:
        if row[0] not in seen:
            seen.add(row[0])
            out.append(row)
    return out


def _data_lines(path: Path, limit: int | None = None) -> Iterator[tuple[int, list[str]]]:
    """(line number, fields) of the non-comment, non-blank lines of a TUM text file (the first ``limit``),
    split one at a time."""
    if not path.exists():
        raise DatasetError(f"{path}: file is missing (a TUM sequence needs rgb.txt and depth.txt)")
    text = read_text_limited(path, what="file list", error=lambda reason: DatasetError(f"{path}: {reason}"))
    found = 0
    for number, line in enumerate(_lines(text), start=1):
        line = line.strip()
        if line and not line.startswith("#"):
            if limit is not None and found >= limit:
                return
            found += 1
            yield number, re.split(r"[\s,]+", line)


def _stamp(path: Path, number: int, field: str) -> float:
    try:
        value = float(field)
    except ValueError:
        raise DatasetError(f"{path}:{number}: timestamp {field!r} is not a number") from None
    if not np.isfinite(value):
        raise DatasetError(f"{path}:{number}: timestamp {field!r} is not finite")
    return value


#: The Kinect's accelerometer readings TUM records beside the images: ``timestamp ax ay az`` (m/s²), axes those of
#: the camera (x right, y down, z forward); at rest the reading is the specific force, which points up.
ACCELEROMETER = "accelerometer.txt"
def read_accelerometer(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Timestamps (N,) and readings (N, 3) of ``accelerometer.txt``, sorted by time; DatasetError naming the
    line for a malformed row."""
    stamps, rows = [], []
    for number, fields in _data_lines(path):
        if len(fields) < 4:
            raise DatasetError(f"{path}:{number}: expected 'timestamp ax ay az', got {len(fields)} fields")
        stamps.append(_stamp(path, number, fields[0]))
        try:
            a = [float(f) for f in fields[1:4]]
        except ValueError:
            raise DatasetError(f"{path}:{number}: acceleration {fields[1:4]} is not three numbers") from None
        if not np.isfinite(a).all():
            raise DatasetError(f"{path}:{number}: acceleration {fields[1:4]} is not finite")
        rows.append(a)
    order = np.argsort(stamps, kind="stable")
    return np.asarray(stamps, np.float64)[order], np.asarray(rows, np.float64).reshape(-1, 3)[order]


def _read_groundtruth(path: Path, strict: bool) -> tuple[np.ndarray, np.ndarray]:
    """``groundtruth.txt`` as :func:`semmap.io.trajectory.read_tum` reads it (``strict``: a non-finite pose
    stops the run instead of leaving frames near it without a pose); its errors as :class:`DatasetError`."""
    try:
        return read_tum(path, strict=strict)
    except FormatError as exc:
        raise DatasetError(str(exc)) from None


def _lines(text: str) -> Iterator[str]:
    """The lines of ``text`` one at a time (no list of them, no copy of the text)."""
    start = 0
    while start < len(text):
        end = text.find("\n", start)
        end = len(text) if end < 0 else end
        yield text[start:end]
        start = end + 1


def read_file_list(path: Path, limit: int | None = None) -> list[tuple[float, str]]:
    """Rows ``(timestamp, relative path)`` of ``rgb.txt`` / ``depth.txt`` in file order (the first ``limit``)."""
    rows = []
    for number, fields in _data_lines(path, limit):
        if len(fields) < 2:
            raise DatasetError(f"{path}:{number}: expected 'timestamp filename', got {' '.join(fields)!r}")
        rows.append((_stamp(path, number, fields[0]), fields[1]))
    return rows


# --------------------------------------------------------------------------------------------------
# Timing
# --------------------------------------------------------------------------------------------------
def associate(first: list[float], second: list[float], max_diff: float) -> list[tuple[int, int]]:
    """One-to-one index pairs ``(i, j)`` with ``|first[i] - second[j]| <= max_diff``, sorted by ``i``.

    Greedy by smallest time difference (as TUM's associate.py): the closest pair overall is taken first, then
    the closest among the stamps still free, and so on.
    """
    a = np.asarray(first, dtype=np.float64)
    b = np.asarray(second, dtype=np.float64)
    order = np.argsort(b, kind="stable")
    b_sorted = b[order]
    lo = np.searchsorted(b_sorted, a - max_diff, side="left")
    hi = np.searchsorted(b_sorted, a + max_diff, side="right")
    candidates = []
    for i in range(len(a)):
        for k in range(lo[i], hi[i]):
            j = int(order[k])
            diff = abs(a[i] - b[j])
            if diff <= max_diff:
                candidates.append((diff, i, j))
    candidates.sort()
    used_a, used_b, pairs = set(), set(), []
    for _, i, j in candidates:
        if i not in used_a and j not in used_b:
            used_a.add(i)
            used_b.add(j)
            pairs.append((i, j))
    return sorted(pairs)


# --------------------------------------------------------------------------------------------------
# Camera
# --------------------------------------------------------------------------------------------------
def _find_intrinsics(root: Path, rgb_paths: list[Path]) -> CameraIntrinsics:
    """``camera.json`` in the root, else the Freiburg calibration named by the folder, else TUM's default
    (:data:`semmap.types.DEFAULT_INTRINSICS`'s focal lengths and centre)."""
    camera = root / CAMERA_FILE
    if camera.exists():
        text = read_text_limited(camera, what="camera file", error=lambda reason: DatasetError(f"{camera}: {reason}"))
        try:
            return CameraIntrinsics.from_dict(json.loads(text))
        except (json.JSONDecodeError, TypeError, AttributeError, KeyError, ValueError) as exc:
            raise DatasetError(f"{camera}: cannot read camera intrinsics: {exc}") from None
        except ConfigError as exc:
            raise DatasetError(f"{camera}: {exc}") from None
    folder = root.resolve().name
    default = (DEFAULT_INTRINSICS.fx, DEFAULT_INTRINSICS.fy, DEFAULT_INTRINSICS.cx, DEFAULT_INTRINSICS.cy)
    fx, fy, cx, cy = next((v for key, v in FREIBURG_INTRINSICS.items() if key in folder), default)
    width, height = image_size(rgb_paths, root)
    return CameraIntrinsics(width, height, fx, fy, cx, cy)


def _open_tum(root: Path, *, labels, raw_color: bool, ros: dict | None, **kwargs) -> TumDataset:
    return TumDataset(root, labels_dir=labels, **kwargs)


#: The TUM RGB-D layout (also what ``semmap simulate`` writes).
FORMAT = FormatEntry("tum", _open_tum, "TUM RGB-D folder: rgb.txt, depth.txt (and groundtruth.txt)",
                     detect=lambda root: (root / "rgb.txt").is_file() and (root / "depth.txt").is_file(),
                     looks_for="rgb.txt and depth.txt (TUM RGB-D)")
