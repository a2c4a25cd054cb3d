"""Segmentation computed elsewhere: a folder of label PNGs or .npy/.npz probability maps, one per frame.

Files are matched to frames by name (``frame-000042.png`` for frame ``frame-000042``) or, failing that, by a
timestamp in the file name within ``max_time_diff`` seconds (``1305031102.175304.npy``).  A frame without a
file gets no semantics (a warning; its geometry and colour are still mapped). A file of another aspect ratio than
its frame, with NaN, or with another class count than the label set is refused, naming the file; one of the same
aspect ratio at another resolution (a network's output grid) is resized to the frame.
"""

from __future__ import annotations

import logging
from pathlib import Path

import cv2
import numpy as np

from semmap.datasets.base import read_label_image
from semmap.errors import ConfigError, FormatError
from semmap.files.parse import is_number
from semmap.types import Frame, LabelSet, TopKProbs

log = logging.getLogger("semmap")

LABELSET_FILE = "labelset.json"
#: Suffixes understood, and name endings stripped to get the frame name (``x.label.png`` -> ``x``).
SUFFIXES = (".png", ".npy", ".npz")
NAME_TAGS = (".label", ".labels", ".probs", ".prob", ".seg")
#: Classes assumed for label PNGs that come without a labelset.json.
FALLBACK_CLASSES = 256
#: Largest relative difference between the aspect ratios of a prediction and its frame (else refused).
ASPECT_TOLERANCE = 0.02


def _frame_key(path: Path) -> str:
    stem = path.name[: -len(path.suffix)]
    for tag in NAME_TAGS:
        if stem.endswith(tag):
            return stem[: -len(tag)]
    return stem


class PrecomputedSegmenter:
    """:class:`~semmap.perception.base.Segmenter` reading per-frame predictions from a folder."""

    name = "precomputed"

    def __init__(self, folder: str | Path, *, label_set: LabelSet | None = None, k: int = 3,
                 label_confidence: float = 0.9, max_time_diff: float = 0.02):
        self.root = Path(folder)
        if not self.root.is_dir():
            raise ConfigError(f"{self.root}: predictions folder does not exist")
        self.k, self.label_confidence, self.max_time_diff = k, label_confidence, max_time_diff
        files = sorted(p for p in self.root.iterdir() if p.suffix.lower() in SUFFIXES and p.is_file())
        if not files:
            raise ConfigError(f"{self.root}: no predictions (.png label maps or .npy/.npz probabilities)")
        self._by_name = {_frame_key(p): p for p in files}
        stamps = [(float(key), p) for key, p in self._by_name.items() if is_number(key)]
        stamps.sort()
        self._stamps = np.array([s for s, _ in stamps], np.float64)
        self._stamp_paths = [p for _, p in stamps]
        self.missing: list[str] = []
        self._label_set = self._choose_label_set(label_set, files)

    def _choose_label_set(self, given: LabelSet | None, files: list[Path]) -> LabelSet:
        """The folder's own labelset.json, else ``given`` (the dataset's classes), else generic classes."""
        path = self.root / LABELSET_FILE
        if path.is_file():
            return LabelSet.load(path)
        if given is not None:
            return given
        first = files[0]
        if first.suffix.lower() == ".png":
            log.info("%s: no %s; assuming %d generic classes", self.root, LABELSET_FILE, FALLBACK_CLASSES)
            return LabelSet.generic(FALLBACK_CLASSES)
        return LabelSet.generic(_load_probabilities(first).shape[-1])

    @property
    def label_set(self) -> LabelSet:
        return self._label_set

    def lookup(self, frame: Frame) -> Path | None:
        """The prediction file of ``frame`` by name, else by nearest timestamp, else None."""
        path = self._by_name.get(frame.name)
        if path is not None or not len(self._stamps):
            return path
        i = int(np.searchsorted(self._stamps, frame.timestamp))
        best = min((j for j in (i - 1, i) if 0 <= j < len(self._stamps)),
                   key=lambda j: abs(self._stamps[j] - frame.timestamp))
        return self._stamp_paths[best] if abs(self._stamps[best] - frame.timestamp) <= self.max_time_diff else None

    def segment(self, frame: Frame) -> TopKProbs | None:
        """Top-k class distribution of ``frame`` from its file (resized to the frame if needed), or None."""
        path = self.lookup(frame)
        if path is None:
            log.warning("frame %s has no prediction in %s; mapped without semantics", frame.name, self.root)
            self.missing.append(frame.name)
            return None
        h, w = frame.depth.shape
        num_classes = len(self._label_set)
        if path.suffix.lower() == ".png":
            ids = read_label_image(path)
            _check_size(ids.shape[:2], (h, w), path, frame)
            if ids.shape != (h, w):
                ids = cv2.resize(ids, (w, h), interpolation=cv2.INTER_NEAREST)
            if int(ids.max(initial=0)) >= num_classes:
                raise FormatError(f"{path}: class id {int(ids.max())} is outside the label set "
                                  f"(0..{num_classes - 1}); add a {LABELSET_FILE}")
            return TopKProbs.from_hard_labels(ids, self.label_confidence, num_classes, self.k)
        probs = _orient(_load_probabilities(path), num_classes, path)
        _check_size(probs.shape[:2], (h, w), path, frame)
        if probs.shape[:2] != (h, w):
            probs = np.dstack([cv2.resize(np.ascontiguousarray(probs[..., c:c + 256]), (w, h),
                                          interpolation=cv2.INTER_LINEAR) for c in range(0, num_classes, 256)])
            probs = probs.reshape(h, w, num_classes)
        return TopKProbs.from_dense(probs, self.k)


def _load_probabilities(path: Path) -> np.ndarray:
    """A probability array from .npy, or from .npz (key ``probs`` or its only array); FormatError otherwise."""
    from semmap.files.safe import read_npy, read_npz_members, regular_file_size

    if path.suffix.lower() == ".npz":
        arrays = read_npz_members(path, what="probabilities file")
        if "probs" in arrays:
            arr = arrays["probs"]
        elif len(arrays) == 1:
            arr = next(iter(arrays.values()))
        else:
            raise FormatError(f"{path}: .npz holds {sorted(arrays)}; name the probabilities 'probs'")
    else:
        size = regular_file_size(path, what="probabilities file")
        try:
            with open(path, "rb") as f:
                arr = read_npy(f, size, what="probabilities", error=lambda reason: FormatError(f"{path}: {reason}"))
        except OSError as exc:
            raise FormatError(f"{path}: cannot read probabilities ({exc})") from None
    if arr.ndim != 3 or not np.issubdtype(arr.dtype, np.floating):
        raise FormatError(f"{path}: probabilities must be a 3-D float array (H, W, K), got {arr.shape} {arr.dtype}")
    return arr


def _check_size(got: tuple[int, ...], want: tuple[int, int], path: Path, frame: Frame) -> None:
    """FormatError naming the file when a prediction's aspect ratio is not its frame's (resizing it would put
    classes on the wrong pixels)."""
    (gh, gw), (h, w) = got, want
    if gh < 1 or gw < 1 or abs((gw / gh) / (w / h) - 1.0) > ASPECT_TOLERANCE:
        raise FormatError(f"{path}: prediction is {gw}x{gh} but frame {frame.name} is {w}x{h} (another aspect "
                          f"ratio); write predictions at the frame's size")


def _orient(probs: np.ndarray, num_classes: int, path: Path) -> np.ndarray:
    """(H, W, K) float32 probabilities (accepting (K, H, W)); checks K and that rows sum to about 1."""
    if probs.shape[-1] != num_classes and probs.shape[0] == num_classes:
        probs = np.moveaxis(probs, 0, -1)
    if probs.shape[-1] != num_classes:
        raise FormatError(f"{path}: probabilities have shape {probs.shape}, expected (H, W, {num_classes}) "
                          f"for the {num_classes} classes of the label set")
    probs = probs.astype(np.float32, copy=False)
    if not np.isfinite(probs).all():
        raise FormatError(f"{path}: probabilities hold NaN or infinite values ({int((~np.isfinite(probs)).sum())} "
                          f"of {probs.size})")
    sums = probs.sum(-1)
    if probs.min() < -1e-3 or np.abs(sums - 1.0).max() > 0.02:
        raise FormatError(f"{path}: values are not per-pixel probabilities (sums range "
                          f"{sums.min():.3f}..{sums.max():.3f}); apply a softmax first")
    return probs
