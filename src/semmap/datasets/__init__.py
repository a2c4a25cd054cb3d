"""Dataset readers: one file per on-disk format, all yielding :class:`semmap.types.Frame` lazily."""

from __future__ import annotations

from pathlib import Path

from semmap.datasets.base import (
    Dataset,
    SkippedFrame,
    UnreadableFileError,
    ensure_folder,
    read_color,
    read_depth,
    read_label_image,
)
from semmap.datasets.label_folder import LabelFolder
from semmap.datasets.rosbag import RosbagDataset, is_rosbag
from semmap.datasets.sevenscenes import SevenScenesDataset
from semmap.datasets.tum import TumDataset
from semmap.errors import DatasetError
from semmap.io.tum_writer import write_tum_sequence

#: Format name -> reader class; every reader takes ``(root, *, stride, max_frames, labels_dir, ...)``.
READERS: dict[str, type] = {
    "tum": TumDataset,
    "7scenes": SevenScenesDataset,
    "rosbag": RosbagDataset,
}


def detect_format(path: str | Path) -> str:
    """Format of the sequence at ``path``: "rosbag" (a ROS 1 .bag, a ROS 2 bag folder), "tum" (rgb.txt +
    depth.txt) or "7scenes" (frame-*.color.*)."""
    if is_rosbag(Path(path)):
        return "rosbag"
    root = ensure_folder(path)
    if (root / "rgb.txt").is_file() and (root / "depth.txt").is_file():
        return "tum"
    if next(root.glob("frame-*.color.*"), None) is not None:
        return "7scenes"
    raise DatasetError(f"{root}: unknown dataset format; looked for rgb.txt and depth.txt (TUM RGB-D), "
                       f"frame-*.color.png|jpg files (7-Scenes) and metadata.yaml (ROS 2 bag)")


def open_dataset(
    path: str | Path,
    format: str = "auto",
    *,
    labels: str | Path | LabelFolder | None = None,
    stride: int = 1,
    max_frames: int | None = None,
    raw_color: bool = False,
    ros: dict | None = None,
    strict: bool = False,
    **kwargs,
) -> Dataset:
    """Open the sequence at ``path`` with the reader for ``format`` ("auto" detects it).

    ``labels`` is an optional folder of per-frame label PNGs (see :class:`LabelFolder`); ``raw_color`` keeps
    colour as stored where the reader would register it onto the depth image (7-Scenes); ``kwargs`` go to the
    reader (e.g. ``depth_scale`` for TUM); ``ros`` holds the ROS bag reader's topic and frame options (ignored
    by the other readers); ``strict`` stops at the first frame that cannot be used instead of skipping it.
    """
    name = detect_format(path) if format == "auto" else format
    if name == "rosbag":
        if not Path(path).exists():
            raise DatasetError(f"{path}: ROS bag does not exist")
        return RosbagDataset(path, labels_dir=labels, stride=stride, max_frames=max_frames, strict=strict,
                             **(ros or {}), **kwargs)
    root = ensure_folder(path)
    if name == "7scenes":
        kwargs["register_color"] = not raw_color
    try:
        reader = READERS[name]
    except KeyError:
        raise DatasetError(f"unknown dataset format {name!r}; known: auto, {', '.join(READERS)}") from None
    return reader(root, labels_dir=labels, stride=stride, max_frames=max_frames, strict=strict, **kwargs)


__all__ = [
    "READERS",
    "Dataset",
    "LabelFolder",
    "RosbagDataset",
    "SevenScenesDataset",
    "SkippedFrame",
    "TumDataset",
    "UnreadableFileError",
    "detect_format",
    "open_dataset",
    "read_color",
    "read_depth",
    "read_label_image",
    "write_tum_sequence",
]
