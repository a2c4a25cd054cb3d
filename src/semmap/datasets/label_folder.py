"""A folder of per-frame class-id PNGs used as a semantic source, matched to frames by file stem."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from semmap.datasets.base import LOG, check_image_size, ensure_folder, read_label_image
from semmap.errors import DatasetError
from semmap.types import CameraIntrinsics, LabelSet

#: File names accepted for frame ``<name>``, in order of preference.
LABEL_SUFFIXES = (".png", ".label.png", ".labels.png")
LABELSET_FILE = "labelset.json"


class LabelFolder:
    """Per-frame label PNGs (``<frame>.png``, ``.label.png`` or ``.labels.png``) and an optional label set.

    ``kind`` only names the images in messages ("label", "instance").
    """

    def __init__(self, root: str | Path, *, kind: str = "label") -> None:
        try:
            self.root = ensure_folder(root)
        except DatasetError as exc:
            raise DatasetError(f"{kind} folder: {exc}") from None
        self.kind = kind
        labelset = self.root / LABELSET_FILE
        self.label_set: LabelSet | None = LabelSet.load(labelset) if labelset.is_file() else None

    def __repr__(self) -> str:
        return f"LabelFolder({str(self.root)!r})"

    def lookup(self, frame_name: str) -> Path | None:
        """Label PNG of the frame named ``frame_name`` (a file stem such as ``frame-000042``), or None."""
        for suffix in LABEL_SUFFIXES:
            path = self.root / f"{frame_name}{suffix}"
            if path.is_file():
                return path
        return None

    def expected_path(self, frame_name: str) -> Path:
        """The file name a frame's labels would have in the plainest form (for messages)."""
        return self.root / f"{frame_name}{LABEL_SUFFIXES[0]}"

    def read(self, frame_name: str, intrinsics: CameraIntrinsics, classes: int | None = None) -> np.ndarray | None:
        """(H, W) uint16 ids for the frame, or None with a warning naming the expected file if it has none;
        a :class:`DatasetError` naming the file and frame when an id lies outside a label set of ``classes``."""
        path = self.lookup(frame_name)
        if path is None:
            LOG.warning("frame %s has no %s image (expected %s); its %ss are left empty",
                        frame_name, self.kind, self.expected_path(frame_name), self.kind)
            return None
        ids = read_label_image(path)
        check_image_size(ids, intrinsics, path, self.kind)
        top = int(ids.max()) if classes is not None and ids.size else -1
        if classes is not None and top >= classes:
            raise DatasetError(f"{path}: label id {top} is outside the label set (0..{classes - 1}) of frame "
                               f"{frame_name}; the label images and {LABELSET_FILE} do not belong together")
        return ids


def as_label_folder(labels: str | Path | LabelFolder | None) -> LabelFolder | None:
    """Accept a folder path or an open :class:`LabelFolder` wherever readers take ``labels_dir``."""
    if labels is None or isinstance(labels, LabelFolder):
        return labels
    return LabelFolder(labels)


def choose_label_set(labels: LabelFolder | None, root: Path) -> LabelSet | None:
    """The label folder's own label set, else ``labelset.json`` in the dataset root, else None."""
    if labels is not None and labels.label_set is not None:
        return labels.label_set
    path = root / LABELSET_FILE
    return LabelSet.load(path) if path.is_file() else None
