"""Dataset readers: one file per on-disk format, all yielding :class:`semmap.types.Frame` lazily."""

from __future__ import annotations

from pathlib import Path

from semmap.datasets import replica, rosbag, scannet, sevenscenes, stills, tum
from semmap.datasets.base import (
    Dataset,
    FormatEntry,
    SkippedFrame,
    UnreadableFileError,
    check_selection,
    ensure_folder,
    read_color,
    read_depth,
    read_label_image,
)
from semmap.datasets.label_folder import LabelFolder
from semmap.datasets.rosbag import RosbagDataset
from semmap.datasets.sevenscenes import SevenScenesDataset
from semmap.datasets.tum import TumDataset
from semmap.errors import DatasetError
from semmap.io.tum_writer import write_tum_sequence
from semmap.registry import Registry

#: Every on-disk format, in the order :func:`detect_format` tries them; each reader module declares its ``FORMAT``.
FORMATS: Registry[FormatEntry] = Registry("dataset format", (rosbag.FORMAT, tum.FORMAT, sevenscenes.FORMAT,
                                                            scannet.FORMAT, replica.FORMAT, stills.FORMAT),
                                      error=DatasetError)
#: ``--format`` value that detects the format.
AUTO = "auto"
#: The format names and ``auto`` as an enum (the type of ``input.format`` in the run configuration).
DatasetFormat = FORMATS.enum("DatasetFormat", __name__, (AUTO,))


def detect_format(path: str | Path) -> str:
    """Name of the format of the sequence at ``path`` (the first of :data:`FORMATS` that recognises it), or a
    DatasetError saying what was looked for."""
    path = Path(path)
    for entry in FORMATS.values():
        if not entry.folder and entry.detect(path):
            return entry.name
    root = ensure_folder(path)
    for entry in FORMATS.values():
        if entry.folder and entry.detect(root):
            return entry.name
    looked = [e.looks_for for e in FORMATS.values() if e.folder] + [e.looks_for for e in FORMATS.values()
                                                                     if not e.folder]
    raise DatasetError(f"{root}: unknown dataset format; looked for {', '.join(looked[:-1])} and {looked[-1]}")


def open_dataset(
    path: str | Path,
    format: str = AUTO,
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
    check_selection(stride, max_frames)  # before a bag is read
    name = detect_format(path) if format == AUTO else format
    if name not in FORMATS or FORMATS[name].folder:
        path = ensure_folder(path)
    if name not in FORMATS:
        raise DatasetError(FORMATS.unknown(name, (AUTO,)))
    return FORMATS[name].factory(path, labels=labels, stride=stride, max_frames=max_frames, strict=strict,
                                 raw_color=raw_color, ros=ros, **kwargs)


__all__ = [
    "AUTO",
    "FORMATS",
    "Dataset",
    "DatasetFormat",
    "FormatEntry",
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
