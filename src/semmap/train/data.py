"""Training data: folders written by ``semmap simulate`` (TUM layout + ``labels/``) or a plain layout of images
and label PNGs (+ depth), loaded into memory at the training input size.

Plain layout (NYUv2 / SUN RGB-D / ADE20K exports)::

    DIR/images/<name>.png|.jpg      colour (``rgb/`` also accepted)
    DIR/labels/<name>.png           8- or 16-bit class ids (0 = unknown / void, not trained on)
    DIR/depth/<name>.png            optional 16-bit depth, ``depth_scale`` units per metre (NYUv2: 1000)
    DIR/labelset.json               optional class names and colours

A class-mapping JSON file maps the data's ids to the trained label set when they differ::

    {"map": {"5": "chair", "6": 7, ...}, "default": 0}

(source id -> target class name or id; unmapped ids get ``default``, 0 = ignored).
"""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from semmap.datasets.base import read_color, read_depth, read_label_image
from semmap.errors import DatasetError
from semmap.types import LabelSet

log = logging.getLogger("semmap")

COLOR_SUFFIXES = (".png", ".jpg", ".jpeg")
PLAIN_IMAGE_DIRS = ("images", "rgb", "image")
LABELSET_FILE = "labelset.json"
#: Depth units per metre: ``semmap simulate`` / TUM write 5000, NYUv2 and SUN RGB-D toolboxes millimetres.
TUM_DEPTH_SCALE = 5000.0
PLAIN_DEPTH_SCALE = 1000.0
#: Largest timestamp gap (s) when pairing TUM colour and depth images.
MAX_TIME_DIFF = 0.02
#: Depth is kept in memory as uint16 millimetres.
DEPTH_MM = 1000.0


@dataclass(frozen=True)
class Sample:
    """One training image: colour, labels and optional depth files."""

    rgb: Path
    label: Path
    depth: Path | None = None
    depth_scale: float = PLAIN_DEPTH_SCALE


@dataclass
class TrainingSet:
    """Images at the training size in memory: rgb (N, H, W, 3) uint8, labels (N, H, W) uint16, depth
    (N, H, W) uint16 millimetres (0 = invalid) or None when any image lacks depth."""

    rgb: np.ndarray
    labels: np.ndarray
    depth: np.ndarray | None
    label_set: LabelSet
    sources: list[str] = field(default_factory=list)

    def __len__(self) -> int:
        return len(self.rgb)


def _is_data_folder(root: Path) -> bool:
    return (root / "rgb.txt").is_file() or any((root / d).is_dir() for d in PLAIN_IMAGE_DIRS)


def data_folders(folder: str | Path) -> list[Path]:
    """``folder`` itself when it holds training images, else its sub-folders that do (a folder of scenes)."""
    root = Path(folder)
    if not root.is_dir():
        raise DatasetError(f"{root}: training data folder does not exist")
    if _is_data_folder(root):
        return [root]
    subs = sorted(p for p in root.iterdir() if p.is_dir() and _is_data_folder(p))
    if not subs:
        raise DatasetError(f"{root}: no training images (expected rgb.txt + labels/, or images/ + labels/, "
                           f"here or in its sub-folders)")
    return subs


def find_samples(folder: str | Path, *, depth_scale: float | None = None) -> tuple[list[Sample], LabelSet | None]:
    """The samples of one folder (simulator / TUM layout or plain layout) and its label set, if it has one."""
    root = Path(folder)
    if not root.is_dir():
        raise DatasetError(f"{root}: training data folder does not exist")
    label_set = LabelSet.load(root / LABELSET_FILE) if (root / LABELSET_FILE).is_file() else None
    if (root / "rgb.txt").is_file():
        samples = _tum_samples(root, depth_scale)
    else:
        samples = _plain_samples(root, PLAIN_DEPTH_SCALE if depth_scale is None else depth_scale)
    if not samples:
        raise DatasetError(f"{root}: no training images (expected rgb.txt + labels/, or images/ + labels/)")
    return samples, label_set


def _tum_samples(root: Path, depth_scale: float | None) -> list[Sample]:
    """Colour images listed in rgb.txt, labels ``labels/<stem>.png``, depth nearest in time from depth.txt."""
    if depth_scale is None:
        depth_scale = TUM_DEPTH_SCALE
        info = root / "scene.json"
        if info.is_file():
            try:
                depth_scale = float(json.loads(info.read_text()).get("depth_scale", TUM_DEPTH_SCALE))
            except (OSError, ValueError, TypeError) as exc:
                raise DatasetError(f"{info}: cannot read the depth scale ({exc})") from None
    rgb = _read_list(root / "rgb.txt")
    depth = _read_list(root / "depth.txt") if (root / "depth.txt").is_file() else []
    stamps = np.array([t for t, _ in depth])
    samples = []
    for t, rel in rgb:
        path = root / rel
        d = None
        if len(stamps):
            i = int(np.argmin(np.abs(stamps - t)))
            d = root / depth[i][1] if abs(stamps[i] - t) <= MAX_TIME_DIFF else None
        samples.append(Sample(path, root / "labels" / f"{path.stem}.png", d, depth_scale))
    return samples


def _read_list(path: Path) -> list[tuple[float, str]]:
    rows = []
    for n, line in enumerate(path.read_text().splitlines(), 1):
        if not line.strip() or line.startswith("#"):
            continue
        parts = line.split()
        try:
            rows.append((float(parts[0]), parts[1]))
        except (IndexError, ValueError):
            raise DatasetError(f"{path}:{n}: expected 'timestamp filename', got {line!r}") from None
    return rows


def _plain_samples(root: Path, depth_scale: float) -> list[Sample]:
    images = next((root / d for d in PLAIN_IMAGE_DIRS if (root / d).is_dir()), None)
    if images is None:
        return []
    depth_dir = root / "depth"
    samples = []
    for path in sorted(p for p in images.iterdir() if p.suffix.lower() in COLOR_SUFFIXES):
        d = depth_dir / f"{path.stem}.png"
        samples.append(Sample(path, root / "labels" / f"{path.stem}.png", d if d.is_file() else None, depth_scale))
    return samples


@dataclass(frozen=True)
class ClassMap:
    """Lookup table source id -> target id (``default`` for ids not listed)."""

    table: np.ndarray  # (65536,) uint16

    @classmethod
    def load(cls, path: str | Path, target: LabelSet) -> ClassMap:
        path = Path(path)
        try:
            d = json.loads(path.read_text())
            mapping = d["map"]
            default = _target_id(d.get("default", 0), target, path)
            table = np.full(65536, default, np.uint16)
            for src, dst in mapping.items():
                table[int(src)] = _target_id(dst, target, path)
        except (OSError, ValueError, KeyError, TypeError, AttributeError, IndexError) as exc:
            raise DatasetError(f"{path}: not a class-mapping file ({{\"map\": {{source id: target}}, "
                               f"\"default\": 0}}): {exc}") from None
        return cls(table)

    def apply(self, labels: np.ndarray) -> np.ndarray:
        return self.table[labels]


def _target_id(value, target: LabelSet, path: Path) -> int:
    if isinstance(value, str) and not value.lstrip("-").isdigit():
        if value not in target.names:
            raise DatasetError(f"{path}: class {value!r} is not in the label set ({', '.join(target.names)})")
        return target.names.index(value)
    v = int(value)
    if not 0 <= v < len(target):
        raise DatasetError(f"{path}: target id {v} is outside the label set (0..{len(target) - 1})")
    return v


def load_training_set(samples: list[Sample], size: tuple[int, int], label_set: LabelSet, *,
                      class_map: ClassMap | None = None, need_depth: bool = False) -> TrainingSet:
    """Read, check and resize every sample to ``size`` (width, height); DatasetError naming the file on a missing
    label, mismatched sizes or a class id outside ``label_set``."""
    w, h = size
    n = len(samples)
    rgb = np.empty((n, h, w, 3), np.uint8)
    labels = np.empty((n, h, w), np.uint16)
    has_depth = all(s.depth is not None for s in samples)
    if need_depth and not has_depth:
        missing = next(s for s in samples if s.depth is None)
        raise DatasetError(f"{missing.rgb}: no depth image for this colour image, and the network needs depth")
    depth = np.empty((n, h, w), np.uint16) if has_depth else None
    k = len(label_set)
    for i, s in enumerate(samples):
        if not s.label.is_file():
            raise DatasetError(f"{s.rgb}: no label image (expected {s.label})")
        color = read_color(s.rgb)
        ids = read_label_image(s.label)
        if ids.shape != color.shape[:2]:
            raise DatasetError(f"{s.label}: label image is {ids.shape[1]}x{ids.shape[0]} but its colour image "
                               f"{s.rgb} is {color.shape[1]}x{color.shape[0]}")
        if class_map is not None:
            ids = class_map.apply(ids)
        top = int(ids.max(initial=0))
        if top >= k:
            raise DatasetError(f"{s.label}: class id {top} is outside the label set (0..{k - 1}); "
                               f"give a class-mapping file (--class-map)")
        rgb[i] = _resize(color, (w, h), cv2.INTER_AREA)
        labels[i] = _resize(ids, (w, h), cv2.INTER_NEAREST)
        if depth is not None:
            dm = read_depth(s.depth, s.depth_scale)
            if dm.shape != color.shape[:2]:
                raise DatasetError(f"{s.depth}: depth image is {dm.shape[1]}x{dm.shape[0]} but its colour image "
                                   f"{s.rgb} is {color.shape[1]}x{color.shape[0]}")
            depth[i] = np.clip(np.rint(_resize(dm, (w, h), cv2.INTER_NEAREST) * DEPTH_MM), 0, 65535)
    return TrainingSet(rgb, labels, depth, label_set, [str(s.rgb) for s in samples])


def _resize(image: np.ndarray, size: tuple[int, int], interpolation: int) -> np.ndarray:
    if image.shape[1] == size[0] and image.shape[0] == size[1]:
        return image
    if interpolation == cv2.INTER_AREA and (image.shape[1] < size[0] or image.shape[0] < size[1]):
        interpolation = cv2.INTER_LINEAR  # enlarging: area averaging has nothing to average
    return cv2.resize(image, size, interpolation=interpolation)


def gather(folders: list[Path], size: tuple[int, int], *, label_set: LabelSet | None = None,
           class_map_path: Path | None = None, depth_scale: float | None = None, need_depth: bool = False
           ) -> TrainingSet:
    """Every sample of ``folders`` (each a data folder or a folder of them) in memory; the label set is the
    given one, else the first folder's labelset.json, else generic classes up to the largest id seen."""
    samples: list[Sample] = []
    found: LabelSet | None = None
    for folder in (f for given in folders for f in data_folders(given)):
        s, ls = find_samples(folder, depth_scale=depth_scale)
        samples += s
        found = found or ls
    target = label_set or found
    if target is None:
        labelled = [s for s in samples if s.label.is_file()]
        if not labelled:
            where = ", ".join(str(f) for f in folders)
            raise DatasetError(f"{where}: none of the {len(samples)} training images has a label image "
                               f"(labels/<image name>.png); add them, or train on a folder written by semmap "
                               f"simulate")
        top = max(int(read_label_image(s.label).max(initial=0)) for s in labelled)
        target = LabelSet.generic(top + 1)
        log.info("no %s in the data; training %d generic classes", LABELSET_FILE, top + 1)
    class_map = ClassMap.load(class_map_path, target) if class_map_path is not None else None
    training = load_training_set(samples, size, target, class_map=class_map, need_depth=need_depth)
    if not training.labels.any():
        raise DatasetError(f"{', '.join(map(str, folders))}: every label pixel is 0 (unknown / void, never trained "
                           f"on) in all {len(samples)} samples{' after --class-map' if class_map else ''}: nothing to "
                           "learn; check the label images and the label set")
    return training
