"""Microsoft 7-Scenes sequences: ``frame-NNNNNN.color.png|jpg``, ``.depth.png`` (mm) and ``.pose.txt``.

Colour and depth come from two cameras: the published intrinsics (f = 585 px) are the depth camera's, the colour
camera has f = 526 px and sits 3 cm beside it, so the raw images disagree by up to 30 pixels at the borders.
The reader registers colour onto the depth image (:func:`semmap.geometry.register_color`) with the colour camera
fitted by ``scripts/calibrate_7scenes_color.py`` when the sequence has the 7-Scenes Kinect's depth intrinsics
(640x480, f = 585 px; folders from other cameras are read as they are); ``register_color=False`` keeps the raw
colour.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from semmap.datasets.base import (
    LOG,
    FormatEntry,
    SequenceReader,
    UnreadableFileError,
    check_image_size,
    ensure_folder,
    image_size,
    read_color,
    read_depth,
)
from semmap.datasets.label_folder import LabelFolder, as_label_folder, choose_label_set
from semmap.errors import ConfigError, DatasetError
from semmap.files.safe import read_text_limited
from semmap.geometry import register_color
from semmap.types import CameraIntrinsics, ColorCamera, Frame, RawColor, check_pose

#: Colour file names; png is preferred when a frame has both.
COLOR_PATTERN = re.compile(r"^(frame-(\d+))\.color\.(png|jpg)$")
INTRINSICS_FILE = "camera-intrinsics.txt"
#: Largest pose or camera-matrix file read (16 numbers; anything far larger is not one).
POSE_FILE_BYTES = 64 * 1024
#: 7-Scenes' documented calibration (fx, fy, cx, cy) when the folder has no camera-intrinsics.txt.
DEFAULT_INTRINSICS = (585.0, 585.0, 320.0, 240.0)
DEPTH_SCALE = 1000.0  # millimetres
FRAME_RATE = 30.0  # Hz, for timestamps
#: The colour camera of the 7-Scenes Kinect relative to its depth camera, fitted by
#: ``scripts/calibrate_7scenes_color.py`` on 40 redkitchen frames (depth outlines against colour edges: mean
#: distance 5.1 px with the depth camera's intrinsics, 3.0 px with these).
SEVEN_SCENES_COLOR_CAMERA = ColorCamera(526.3, 526.3, 322.5, 236.2, (-0.0316, 0.0061, 0.0))
#: ... and its depth camera, the published 7-Scenes intrinsics: colour is registered for sequences that have them
SEVEN_SCENES_DEPTH_CAMERA = CameraIntrinsics(640, 480, *DEFAULT_INTRINSICS)


@dataclass(frozen=True)
class _SevenScenesRef:
    """Files of one 7-Scenes frame."""

    index: int
    name: str
    color: Path

    def sibling(self, suffix: str) -> Path:
        return self.color.with_name(f"{self.name}{suffix}")


class SevenScenesDataset(SequenceReader[_SevenScenesRef]):
    """7-Scenes sequence folder; ``index`` is the frame number, ``timestamp = index / 30`` s.

    Depth is uint16 millimetres with 0 and 65535 invalid; poses are camera-to-world (``T_world_cam``).
    """

    depth_units = DEPTH_SCALE

    def __init__(
        self,
        root: str | Path,
        *,
        intrinsics: CameraIntrinsics | None = None,
        stride: int = 1,
        max_frames: int | None = None,
        labels_dir: str | Path | LabelFolder | None = None,
        register_color: bool = True,
        strict: bool = False,
    ) -> None:
        root = ensure_folder(root)
        refs = find_frames(root)
        if intrinsics is None:
            intrinsics = _find_intrinsics(root, [r.color for r in refs])
        self._labels = as_label_folder(labels_dir)
        super().__init__(root, refs, stride=stride, max_frames=max_frames, intrinsics=intrinsics,
                         label_set=choose_label_set(self._labels, root), strict=strict)
        #: whether colour is registered onto depth (asked for, and the camera is the 7-Scenes Kinect)
        self.registers_color = bool(register_color) and intrinsics == SEVEN_SCENES_DEPTH_CAMERA

    def _load(self, ref: _SevenScenesRef) -> Frame:
        cam = self._intrinsics
        pose = read_pose(ref.sibling(".pose.txt"))
        rgb = read_color(ref.color)
        check_image_size(rgb, cam, ref.color, "colour")
        depth_path = ref.sibling(".depth.png")
        depth = read_depth(depth_path, DEPTH_SCALE, invalid_values=(0, 65535))
        check_image_size(depth, cam, depth_path, "depth")
        raw = None
        if self.registers_color:
            raw = RawColor(rgb, SEVEN_SCENES_COLOR_CAMERA)
            rgb = register_color(rgb, depth, cam, SEVEN_SCENES_COLOR_CAMERA)
        return Frame(
            index=ref.index,
            timestamp=ref.index / FRAME_RATE,
            rgb=rgb,
            depth=depth,
            intrinsics=cam,
            T_world_cam=pose,
            labels=self._labels.read(ref.name, cam, self._classes()) if self._labels else None,
            name=ref.name,
            raw_color=raw,
        )


def find_frames(root: Path) -> list[_SevenScenesRef]:
    """One record per ``frame-N.color.*`` file, sorted by frame number."""
    found: dict[int, _SevenScenesRef] = {}
    for path in root.iterdir():
        match = COLOR_PATTERN.match(path.name)
        if match is None:
            continue
        number = int(match.group(2))
        if number in found and found[number].color.suffix == ".png":
            continue
        found[number] = _SevenScenesRef(number, match.group(1), path)
    return [found[n] for n in sorted(found)]


def read_pose(path: Path) -> np.ndarray:
    """4x4 ``T_world_cam`` from a 7-Scenes pose file; a missing, malformed or non-finite pose is
    :class:`UnreadableFileError` (the frame is skipped)."""
    if not path.exists():
        raise UnreadableFileError(path, "pose file is missing")
    text = read_text_limited(path, POSE_FILE_BYTES, what="pose file",
                             error=lambda reason: UnreadableFileError(path, reason))
    try:
        values = np.array([float(v) for v in text.split()], dtype=np.float64)
    except ValueError:
        raise UnreadableFileError(path, "pose file must hold 16 numbers (a 4x4 matrix)") from None
    if values.size != 16:
        raise UnreadableFileError(path, f"pose file must hold 16 numbers (a 4x4 matrix), got {values.size}")
    try:
        return check_pose(values.reshape(4, 4), str(path))
    except DatasetError as exc:
        raise UnreadableFileError(path, str(exc).removeprefix(f"{path}: ")) from None


def _find_intrinsics(root: Path, color_paths: list[Path]) -> CameraIntrinsics:
    """K from ``camera-intrinsics.txt`` (3x3) or 7-Scenes' default; the size from the first colour image."""
    path = root / INTRINSICS_FILE
    if path.exists():
        text = read_text_limited(path, POSE_FILE_BYTES, what="camera matrix",
                                 error=lambda reason: DatasetError(f"{path}: {reason}"))
        try:
            K = np.array([float(v) for v in text.split()], dtype=np.float64)
        except ValueError as exc:
            raise DatasetError(f"{path}: cannot read camera matrix: {exc}") from None
        if K.size != 9 or not np.isfinite(K).all():
            raise DatasetError(f"{path}: expected a finite 3x3 camera matrix, got {K.size} values")
        fx, fy, cx, cy = K[0], K[4], K[2], K[5]
    else:
        fx, fy, cx, cy = DEFAULT_INTRINSICS
    width, height = image_size(color_paths, root)
    if not path.exists():
        LOG.warning("%s: no %s; assuming the 7-Scenes Kinect's depth camera: fx = %g, fy = %g, cx = %g, cy = %g "
                    "px for %dx%d images", root, INTRINSICS_FILE, fx, fy, cx, cy, width, height)
    try:
        return CameraIntrinsics(width, height, float(fx), float(fy), float(cx), float(cy))
    except ConfigError as exc:
        raise DatasetError(f"{path}: {exc}") from None


def _open_7scenes(root: Path, *, labels, raw_color: bool, ros: dict | None, **kwargs) -> SevenScenesDataset:
    return SevenScenesDataset(root, labels_dir=labels, register_color=not raw_color, **kwargs)


#: Microsoft's 7-Scenes layout.
FORMAT = FormatEntry("7scenes", _open_7scenes, "7-Scenes sequence folder: frame-*.color.png, .depth.png, .pose.txt",
                     detect=lambda root: next(root.glob("frame-*.color.*"), None) is not None,
                     looks_for="frame-*.color.png|jpg files (7-Scenes)")
