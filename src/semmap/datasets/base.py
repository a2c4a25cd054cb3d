"""What every dataset reader shares: the ``Dataset`` protocol, image loading and the skip-a-bad-frame rule.

One skip policy for damaged input: a frame whose file is missing or undecodable, whose image has the wrong size or
whose pose is not finite costs that frame (a warning naming the file, the frame recorded in ``skipped`` and the
report); with ``strict`` the first such frame stops the run with a :class:`DatasetError` naming the file. A
sequence that is wrong as a whole (no frames, unreadable index files, unknown format) raises at once.
"""

from __future__ import annotations

import logging
from abc import ABC, abstractmethod
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Generic, Protocol, TypeVar, runtime_checkable

import cv2
import numpy as np

from semmap.errors import DatasetError
from semmap.files.safe import MAX_IMAGE_BYTES, read_bytes_limited
from semmap.limits import check
from semmap.types import CameraIntrinsics, Frame, LabelSet

LOG = logging.getLogger("semmap")
#: Median depths (m) of a frame outside this range make a wrong depth unit likely (warned once per sequence).
PLAUSIBLE_MEDIAN_DEPTH = (0.05, 20.0)
#: Depth units per metre in common use: metres, millimetres, TUM's fifths of a millimetre, tenths of a mm.
COMMON_DEPTH_SCALES = (1.0, 1000.0, 5000.0, 10000.0)


@dataclass(frozen=True)
class SkippedFrame:
    """A frame left out while iterating because one of its files was missing or unreadable."""

    name: str
    path: str
    reason: str


class UnreadableFileError(DatasetError):
    """A frame's file is missing, empty or cannot be decoded; readers skip that frame and go on."""

    def __init__(self, path: str | Path, reason: str) -> None:
        super().__init__(f"{path}: {reason}")
        self.path = str(path)
        self.reason = reason


@runtime_checkable
class Dataset(Protocol):
    """A sequence of RGB-D frames read lazily, one frame in memory at a time."""

    @property
    def name(self) -> str: ...

    @property
    def intrinsics(self) -> CameraIntrinsics: ...

    @property
    def label_set(self) -> LabelSet | None: ...

    @property
    def skipped(self) -> list[SkippedFrame]: ...

    def __iter__(self) -> Iterator[Frame]: ...

    def __len__(self) -> int: ...


# --------------------------------------------------------------------------------------------------
# Image loading
# --------------------------------------------------------------------------------------------------
def _decode(path: str | Path) -> np.ndarray:
    """Image as stored (any depth and channels); :class:`UnreadableFileError` if missing or corrupt."""
    path = Path(path)
    data = read_bytes_limited(path, MAX_IMAGE_BYTES, what="image file",
                              error=lambda reason: UnreadableFileError(path, reason))
    if not data:
        raise UnreadableFileError(path, "file is empty")
    try:
        image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    except cv2.error:
        image = None
    if image is None:
        raise UnreadableFileError(path, "cannot decode image (corrupt or truncated)")
    return image


def read_color(path: str | Path) -> np.ndarray:
    """Colour image as (H, W, 3) uint8 in RGB order (grey and BGRA files are converted)."""
    image = _decode(path)
    if image.dtype != np.uint8:
        raise DatasetError(f"{path}: colour image must be 8-bit, got {image.dtype}")
    if image.ndim == 2:
        return cv2.cvtColor(image, cv2.COLOR_GRAY2RGB)
    channels = image.shape[2]
    if channels == 3:
        return cv2.cvtColor(image, cv2.COLOR_BGR2RGB)
    if channels == 4:
        return cv2.cvtColor(image, cv2.COLOR_BGRA2RGB)
    raise DatasetError(f"{path}: colour image has {channels} channels, expected 3")


def read_depth(path: str | Path, scale: float, invalid_values: Sequence[int] = (0, 65535)) -> np.ndarray:
    """Depth image as (H, W) float32 metres (stored value / ``scale``), 0 where the value is invalid."""
    raw = _decode(path)
    if raw.ndim != 2:
        raise DatasetError(f"{path}: depth image must have one channel, got {raw.shape[2]}")
    if raw.dtype not in (np.uint16, np.uint8):
        raise DatasetError(f"{path}: depth image must be 8- or 16-bit integers, got {raw.dtype}")
    depth = raw.astype(np.float32) / np.float32(scale)
    if len(invalid_values):
        depth[np.isin(raw, np.asarray(invalid_values))] = 0.0
    return depth


def depth_unit_warning(depth: np.ndarray, scale: float | None, where: str | Path) -> str | None:
    """A one-line warning when the median valid depth of ``depth`` (metres, read at ``scale`` units per metre) is
    implausible for an indoor sensor, with the likely scale; None when it is plausible or there is no depth."""
    valid = depth[np.isfinite(depth) & (depth > 0)]
    if valid.size == 0:
        return None
    median = float(np.median(valid))
    low, high = PLAUSIBLE_MEDIAN_DEPTH
    if low <= median <= high:
        return None
    hint = "check the depth unit"
    if scale is not None:
        stored = median * scale  # the median in stored units: the likely scale brings it nearest 2 m
        likely = min(COMMON_DEPTH_SCALES, key=lambda c: abs(np.log(stored / c / 2.0)))
        hint = (f"the depth images look stored at {likely:g} units per metre, not {scale:g} (depth_scale, "
                f"--depth-scale {likely:g})")
    return f"{where}: median depth of the first frame is {median:.3g} m, implausible for metres; {hint}"


def read_label_image(path: str | Path) -> np.ndarray:
    """Class-id image (8- or 16-bit single-channel PNG) as (H, W) uint16."""
    image = _decode(path)
    if image.ndim != 2:
        raise DatasetError(f"{path}: label image must be single-channel class ids, "
                           f"got {image.shape[2]} channels (a colour rendering?)")
    if image.dtype not in (np.uint8, np.uint16):
        raise DatasetError(f"{path}: label image must be 8- or 16-bit, got {image.dtype}")
    return image.astype(np.uint16, copy=False)


def check_image_size(image: np.ndarray, intrinsics: CameraIntrinsics, path: str | Path, what: str) -> None:
    """Raise :class:`UnreadableFileError` (the frame is skipped) naming ``path`` unless the image matches the
    camera size."""
    h, w = image.shape[:2]
    if (w, h) != (intrinsics.width, intrinsics.height):
        raise UnreadableFileError(path, f"{what} image is {w}x{h}, "
                                  f"expected {intrinsics.width}x{intrinsics.height} (the camera intrinsics)")


def image_size(paths: Sequence[Path], where: str | Path) -> tuple[int, int]:
    """(width, height) of the first decodable colour image in ``paths``, for intrinsics without a size."""
    for path in paths:
        try:
            h, w = read_color(path).shape[:2]
        except UnreadableFileError:
            continue
        return w, h
    raise DatasetError(f"{where}: no readable colour image to take the camera size from "
                       f"({len(paths)} candidate frames)")


# --------------------------------------------------------------------------------------------------
# Iteration
# --------------------------------------------------------------------------------------------------
def load_or_skip(load: Callable[[], Frame], name: str, skipped: list[SkippedFrame], *,
                 strict: bool = False) -> Frame | None:
    """``load()``, or None with a warning and a ``skipped`` entry when the frame cannot be used (``strict``: a
    :class:`DatasetError` instead)."""
    try:
        return load()
    except UnreadableFileError as exc:
        skip_frame(name, exc.path, exc.reason, skipped, strict=strict)
        return None


def skip_frame(name: str, path: str, reason: str, skipped: list[SkippedFrame], *, strict: bool = False) -> None:
    """Record a frame left out (a warning and a ``skipped`` entry), or stop the run when ``strict``."""
    if strict:
        raise DatasetError(f"{path}: {reason} (frame {name}; without --strict such a frame is skipped)")
    LOG.warning("skipping frame %s: %s: %s", name, path, reason)
    skipped.append(SkippedFrame(name, path, reason))


T = TypeVar("T")


def check_selection(stride: int, max_frames: int | None) -> None:
    """``stride`` and ``max_frames`` within their limits (``semmap.limits``); ``max_frames`` 0 selects nothing."""
    check("stride", stride, "--stride")
    if max_frames != 0:
        check("max_frames", max_frames, "--max-frames")


def select_frames(items: Sequence[T], stride: int, max_frames: int | None) -> list[T]:
    """Every ``stride``-th item, at most ``max_frames`` of them."""
    check_selection(stride, max_frames)
    chosen = list(items[:: int(stride)])
    return chosen if max_frames is None else chosen[: int(max_frames)]


class FrameRef(Protocol):
    """The minimum a reader's per-frame record carries: the frame name."""

    @property
    def name(self) -> str: ...


R = TypeVar("R", bound=FrameRef)


class SequenceReader(ABC, Generic[R]):
    """Shared reader plumbing: stride / max_frames selection, lazy loading, the skip rule and a warning when the
    first frame's depth is implausible for its unit.

    Subclasses build one record per candidate frame and implement :meth:`_load` for one record.
    """

    #: Stored depth units per metre (None: not a fixed integer scale), named in the depth-unit warning.
    depth_units: float | None = None

    def __init__(self, root: Path, refs: Sequence[R], *, stride: int, max_frames: int | None,
                 intrinsics: CameraIntrinsics, label_set: LabelSet | None, strict: bool = False) -> None:
        self._root = root
        self._strict = strict
        self._refs = select_frames(refs, stride, max_frames)
        self._skipped: list[SkippedFrame] = []
        self._intrinsics = intrinsics
        self._label_set = label_set
        self._depth_checked = False

    @property
    def name(self) -> str:
        return self._root.resolve().name

    @property
    def root(self) -> Path:
        return self._root

    @property
    def skipped(self) -> list[SkippedFrame]:
        """Frames left out by the latest pass (reset when a new pass starts)."""
        return self._skipped

    @property
    def intrinsics(self) -> CameraIntrinsics:
        return self._intrinsics

    @property
    def label_set(self) -> LabelSet | None:
        return self._label_set

    def __len__(self) -> int:
        return len(self._refs)

    def _classes(self) -> int | None:
        """Classes of the label set that label images must stay within (None: no label set, any id)."""
        return None if self._label_set is None else len(self._label_set)

    def __iter__(self) -> Iterator[Frame]:
        self._skipped.clear()
        for ref in self._refs:
            frame = load_or_skip(lambda ref=ref: self._load(ref), ref.name, self._skipped, strict=self._strict)
            if frame is not None:
                if not self._depth_checked:
                    self._depth_checked = True
                    warning = depth_unit_warning(frame.depth, self.depth_units, self._root)
                    if warning:
                        LOG.warning("%s", warning)
                yield frame

    @abstractmethod
    def _load(self, ref: R) -> Frame:
        """Read one frame; raise :class:`UnreadableFileError` for a missing or corrupt file."""


def ensure_folder(root: str | Path) -> Path:
    """``root`` as a Path, or :class:`DatasetError` when it is not an existing folder."""
    path = Path(root)
    if not path.exists():
        raise DatasetError(f"{path}: dataset folder does not exist")
    if not path.is_dir():
        raise DatasetError(f"{path}: is a file, expected a dataset folder (or a ROS bag: .bag, .mcap, .db3)")
    return path


@dataclass(frozen=True)
class FormatEntry:
    """An on-disk dataset format, declared as ``FORMAT`` by its reader's module and found by
    :data:`semmap.datasets.FORMATS`: its name, opener, one line of help, and how to recognise it."""

    name: str
    #: ``open(path, *, labels, stride, max_frames, strict, raw_color, ros, **reader_kwargs) -> Dataset``
    factory: Callable[..., Dataset]
    help: str
    detect: Callable[[Path], bool]  #: True when ``path`` holds this format
    looks_for: str  #: what :attr:`detect` looks for, for the "unknown format" message
    folder: bool = True  #: a folder (checked with :func:`ensure_folder` before ``detect`` and ``factory``)
