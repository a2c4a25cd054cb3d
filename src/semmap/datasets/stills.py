"""A folder of still RGB-D frames without poses, as labelled real-frame sets come (NYU Depth v2's labelled frames,
ScanNet frames exported as images): colour, depth and optional class-id PNGs in sibling folders, matched by file
stem.

- colour: ``rgb/``, ``color/``, ``colour/``, ``image/`` or ``images/`` (PNG or JPEG);
- depth: ``depth/``, 16-bit PNG in millimetres (``camera.json``'s ``depth_scale`` says otherwise), or ``.npy``
  float metres;
- labels: ``labels/``, ``label/``, ``label40/``, ``label-filt/`` or ``semantic/``: class ids, 0 void, NYU-40 unless
  a ``labelset.json`` in or beside the folder names them;
- camera: ``camera.json`` (semmap's), ``intrinsics.txt`` (fx fy cx cy, or a 3x3 / 4x4 matrix) or ScanNet's
  ``intrinsic/intrinsic_depth.txt``, else the Kinect v1 of NYU Depth v2 (with a warning).
"""

from __future__ import annotations

import json
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
from semmap.datasets.label_folder import LABELSET_FILE, LabelFolder, as_label_folder
from semmap.errors import DatasetError
from semmap.files.safe import read_text_limited
from semmap.labels import nyu40_labels
from semmap.types import CameraIntrinsics, Frame, LabelSet

COLOR_FOLDERS = ("rgb", "color", "colour", "image", "images")
DEPTH_FOLDER = "depth"
LABEL_FOLDERS = ("labels", "label", "label40", "label-filt", "semantic")
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")
#: NYU Depth v2's Kinect v1 (its toolbox's colour camera), 640x480.
NYU_INTRINSICS = (518.857901, 519.469611, 325.582449, 253.736166)
#: Stored depth units per metre unless camera.json says otherwise (millimetres).
DEFAULT_DEPTH_SCALE = 1000.0


@dataclass(frozen=True)
class _FrameFiles:
    index: int
    name: str
    rgb: Path
    depth: Path


def _first_folder(root: Path, names: tuple[str, ...]) -> Path | None:
    return next((root / n for n in names if (root / n).is_dir()), None)


def is_frames_folder(root: Path) -> bool:
    """A colour folder and a depth folder side by side, and no TUM lists (``rgb.txt``)."""
    return (_first_folder(root, COLOR_FOLDERS) is not None and (root / DEPTH_FOLDER).is_dir()
            and not (root / "rgb.txt").is_file())


def _by_stem(folder: Path, suffixes: tuple[str, ...]) -> dict[str, Path]:
    return {p.stem: p for p in sorted(folder.iterdir()) if p.is_file() and p.suffix.lower() in suffixes}


def _read_intrinsics(root: Path, size: tuple[int, int]) -> tuple[CameraIntrinsics, float]:
    """The camera and depth scale of the folder (see the module docstring for where they are looked for)."""
    width, height = size
    camera = root / "camera.json"
    if camera.is_file():
        text = read_text_limited(camera, what="camera file", error=lambda r: DatasetError(f"{camera}: {r}"))
        try:
            data = json.loads(text)
            return CameraIntrinsics.from_dict(data), float(data.get("depth_scale", DEFAULT_DEPTH_SCALE))
        except (ValueError, TypeError, KeyError, AttributeError) as exc:
            raise DatasetError(f"{camera}: cannot read camera intrinsics: {exc}") from None
    for path in (root / "intrinsics.txt", root / "intrinsic" / "intrinsic_depth.txt"):
        if path.is_file():
            text = read_text_limited(path, what="intrinsics", error=lambda r, p=path: DatasetError(f"{p}: {r}"))
            try:
                values = np.array(text.replace(",", " ").split(), np.float64)
            except ValueError:
                raise DatasetError(f"{path}: intrinsics must be numbers (fx fy cx cy, or a 3x3 / 4x4 matrix)") \
                    from None
            if values.size == 4:
                fx, fy, cx, cy = values
            elif values.size in (9, 16):
                m = values.reshape(3 if values.size == 9 else 4, -1)
                fx, fy, cx, cy = m[0, 0], m[1, 1], m[0, 2], m[1, 2]
            else:
                raise DatasetError(f"{path}: expected fx fy cx cy or a 3x3 / 4x4 matrix, got {values.size} numbers")
            return CameraIntrinsics(width, height, float(fx), float(fy), float(cx), float(cy)), DEFAULT_DEPTH_SCALE
    fx, fy, cx, cy = NYU_INTRINSICS
    sx, sy = width / 640.0, height / 480.0
    LOG.warning("%s: no camera.json or intrinsics.txt: assuming NYU Depth v2's Kinect (fx %.1f) scaled to %dx%d",
                root, fx, width, height)
    return CameraIntrinsics(width, height, fx * sx, fy * sy, cx * sx, cy * sy), DEFAULT_DEPTH_SCALE


class FramesFolder(SequenceReader[_FrameFiles]):
    """Still frames matched by stem (see the module docstring); frames without a depth image are left out with
    one line naming how many."""

    def __init__(self, root: str | Path, *, labels: str | Path | None = None, stride: int = 1,
                 max_frames: int | None = None, strict: bool = False) -> None:
        root = ensure_folder(root)
        color_dir = _first_folder(root, COLOR_FOLDERS)
        if color_dir is None or not (root / DEPTH_FOLDER).is_dir():
            raise DatasetError(f"{root}: a frames folder needs a colour folder ({'/'.join(COLOR_FOLDERS)}) and "
                               f"{DEPTH_FOLDER}/")
        colors = _by_stem(color_dir, IMAGE_SUFFIXES)
        depths = _by_stem(root / DEPTH_FOLDER, (".png", ".npy"))
        refs = [_FrameFiles(i, stem, colors[stem], depths[stem])
                for i, stem in enumerate(s for s in sorted(colors) if s in depths)]
        if not refs:
            raise DatasetError(f"{root}: no colour image in {color_dir.name}/ has a depth image of the same name "
                               f"in {DEPTH_FOLDER}/")
        if len(refs) < len(colors):
            LOG.info("%s: %d of %d colour images have no depth image; left out", root, len(colors) - len(refs),
                     len(colors))
        self._labels = as_label_folder(labels)
        if self._labels is None and _first_folder(root, LABEL_FOLDERS) is not None:
            self._labels = LabelFolder(_first_folder(root, LABEL_FOLDERS))
        label_set: LabelSet | None = None
        if self._labels is not None:
            beside = self._labels.root.parent / LABELSET_FILE
            label_set = self._labels.label_set or (LabelSet.load(beside) if beside.is_file() else nyu40_labels())
        intrinsics, self.depth_units = _read_intrinsics(root, image_size([r.rgb for r in refs[:1]], root))
        super().__init__(root, refs, stride=stride, max_frames=max_frames, intrinsics=intrinsics,
                         label_set=label_set, strict=strict)

    def _load(self, ref: _FrameFiles) -> Frame:
        cam = self._intrinsics
        rgb = read_color(ref.rgb)
        check_image_size(rgb, cam, ref.rgb, "colour")
        if ref.depth.suffix == ".npy":
            try:
                depth = np.load(ref.depth, allow_pickle=False).astype(np.float32)
            except (OSError, ValueError) as exc:
                raise UnreadableFileError(ref.depth, f"not a depth array ({exc})") from None
            depth[~np.isfinite(depth)] = 0.0
        else:
            depth = read_depth(ref.depth, self.depth_units)
        check_image_size(depth, cam, ref.depth, "depth")
        labels = self._labels.read(ref.name, cam, self._classes()) if self._labels else None
        return Frame(index=ref.index, timestamp=0.0, rgb=rgb, depth=depth, intrinsics=cam,
                     labels=labels, name=ref.name)


def _open_frames(root: Path, *, labels, raw_color: bool, ros: dict | None, **kwargs) -> FramesFolder:
    return FramesFolder(root, labels=labels, **kwargs)


FORMAT = FormatEntry("stills", _open_frames, "still RGB-D frames without poses: rgb|color|image/, depth/ (mm PNG) "
                     "and labels|label40/ matched by name (NYU Depth v2 style)", detect=is_frames_folder,
                     looks_for="rgb|color|image/ beside depth/ (still frames)")
