"""Oracle segmenter: class probabilities made from a frame's ground-truth labels, with controlled errors.

Three presets:

- ``"voxel-grid-paper"`` (Semantic Voxel Grid Mapping, Sec. IV-B): 0.9 on the true class and the remaining
  0.1 spread evenly over the other real classes (ids 1..K-1); no errors. The top-3 then holds the true class and
  the two lowest-id other classes, the rest of the mass is "others".
- ``"cnn-like"``: about 75 % pixel accuracy with the structure a real network's errors have - object boundaries
  shifted by a few pixels, whole objects (or large parts) systematically confused with a similar class
  (chair/sofa, table/desk, cabinet/shelf, monitor/picture, cup/bottle, ...), blotchy patches, small false blobs,
  and frame-to-frame flicker - with soft probabilities: the predicted class 0.5-0.9, the second choice often
  the true class.
- ``"independent"``: the same accuracy and soft probabilities, but every error drawn independently per pixel and
  per frame (uniformly placed, a uniformly random wrong class): errors that multi-view fusion can undo completely,
  the counterpart of ``cnn-like``'s structured ones.

How errors are placed: every pixel gets an error score (near a boundary, inside an object flagged for
confusion this frame, inside a false blob, plus smooth noise); exactly ``round((1 - accuracy) * N)`` of the N
labelled pixels with the highest scores are made wrong, so the measured accuracy equals the setting. Per-object
confusion propensities persist across frames (systematic errors); everything else is drawn from a per-frame
generator seeded by ``(seed, frame.index)``, so results do not depend on call order.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, fields, replace

import cv2
import numpy as np

from semmap.errors import ConfigError, DatasetError
from semmap.types import EMPTY_LABEL, Frame, LabelSet, TopKProbs

#: Pairs of classes a segmentation network typically mixes up (by name; missing names are ignored).
CONFUSIONS: dict[str, tuple[str, ...]] = {
    "chair": ("sofa",), "sofa": ("chair", "bed"), "table": ("desk", "counter"), "desk": ("table",),
    "cabinet": ("shelf", "nightstand"), "shelf": ("cabinet",), "monitor": ("picture",), "picture": ("monitor",),
    "cup": ("bottle",), "bottle": ("cup",), "pillow": ("sofa", "bed"), "bed": ("sofa",), "door": ("wall",),
    "window": ("picture",), "curtain": ("window", "wall"), "counter": ("cabinet", "table"),
    "nightstand": ("cabinet",), "whiteboard": ("picture", "wall"), "book": ("shelf",), "keyboard": ("desk",),
    "box": ("cabinet",), "refrigerator": ("cabinet",), "sink": ("counter",), "wall": ("door", "ceiling"),
    "floor": ("wall",), "ceiling": ("wall",), "person": ("chair",), "lamp": ("plant",), "plant": ("lamp",),
}
_STREAM = 0x0AC1E
#: Classes a network segments easily (large, flat), and their relative proneness to blotchy errors.
STUFF = frozenset({"wall", "floor", "ceiling"})
STUFF_DIFFICULTY = 0.35


@dataclass(frozen=True)
class OracleSettings:
    """Error model of the oracle; see the module docstring. Probabilities are per frame unless noted."""

    pixel_accuracy: float = 0.75
    accuracy_jitter: float = 0.03  # per-frame accuracy varies uniformly by +- this much
    soft: bool = True  # soft CNN-like probabilities; False: ``true_prob`` and an even spread
    true_prob: float = 0.9
    boundary_px: float = 5.0  # width scale (pixels) of the error band along class boundaries
    boundary_weight: float = 1.0
    noise_weight: float = 0.6  # weight of the smooth blotch field
    noise_cell_px: int = 40  # size of the blotches
    flip_p: float = 0.12  # chance an object is confused this frame (scaled by its persistent propensity)
    blobs_per_frame: float = 2.0
    blob_radius_px: tuple[int, int] = (6, 28)
    conf_range: tuple[float, float] = (0.5, 0.9)  # probability of the predicted class
    second_is_true_p: float = 0.75  # for wrong pixels: chance the second choice is the true class
    independent: bool = False  # errors placed uniformly at random, wrong classes uniform (no structure)

    def __post_init__(self) -> None:
        if not 0.0 <= self.pixel_accuracy <= 1.0:
            raise ConfigError(f"pixel_accuracy must be in [0, 1], got {self.pixel_accuracy}")
        if not 0.0 < self.true_prob <= 1.0:
            raise ConfigError(f"true_prob must be in (0, 1], got {self.true_prob}")
        lo, hi = self.conf_range
        if not 0.5 <= lo <= hi <= 1.0:
            raise ConfigError(f"conf_range must satisfy 0.5 <= lo <= hi <= 1, got {self.conf_range}")


PRESETS: dict[str, OracleSettings] = {
    "voxel-grid-paper": OracleSettings(pixel_accuracy=1.0, accuracy_jitter=0.0, soft=False, true_prob=0.9,
                                       flip_p=0.0, blobs_per_frame=0.0),
    "cnn-like": OracleSettings(),
    "independent": OracleSettings(accuracy_jitter=0.0, independent=True),
}


class OracleSegmenter:
    """:class:`~semmap.perception.base.Segmenter` that degrades ground-truth labels in a controlled way.

    ``overrides`` replace fields of the preset's :class:`OracleSettings` (e.g. ``pixel_accuracy=0.8``).
    """

    name = "oracle"

    def __init__(self, label_set: LabelSet, *, preset: str = "cnn-like", seed: int = 0, k: int = 3,
                 **overrides) -> None:
        if preset not in PRESETS:
            raise ConfigError(f"unknown oracle preset {preset!r}; choose one of {', '.join(PRESETS)}")
        names = {f.name for f in fields(OracleSettings)}
        unknown = set(overrides) - names
        if unknown:
            raise ConfigError(f"unknown oracle setting(s) {', '.join(sorted(unknown))}; "
                              f"known: {', '.join(sorted(names))}")
        if k < 1:
            raise ConfigError(f"k must be >= 1, got {k}")
        if len(label_set) < 3:
            raise ConfigError("the oracle needs a label set with at least two real classes besides 'unknown'")
        self._label_set = label_set
        self.preset = preset
        self.settings = replace(PRESETS[preset], **overrides)
        self.seed = int(seed)
        self.k = int(k)
        K = len(label_set)
        self._partner = np.zeros((K, 2), np.int32)  # two confusion partners per class (0 = none)
        for cid, name in enumerate(label_set.names):
            partners = [label_set.names.index(p) for p in CONFUSIONS.get(name, ()) if p in label_set.names]
            for j in range(2):
                self._partner[cid, j] = partners[j] if j < len(partners) else (partners[0] if partners else 0)
        self._propensity = np.random.default_rng([_STREAM, self.seed, 1]).random(1 << 16).astype(np.float32)
        #: how prone each class is to blotchy errors: large flat "stuff" is easy, objects are hard
        self._difficulty = np.array([STUFF_DIFFICULTY if n in STUFF else 1.0 for n in label_set.names], np.float32)
        self._paper_others = self._lowest_others(K)
        #: a fixed other real class for each class (c + 1, wrapping to 1), to resolve collisions
        self._next_class = (1 + np.arange(K) % (K - 1)).astype(np.int32)

    @property
    def label_set(self) -> LabelSet:
        return self._label_set

    def segment(self, frame: Frame) -> TopKProbs:
        """(H, W, k) top-k class distribution for ``frame``, derived from ``frame.labels``."""
        if frame.labels is None:
            raise DatasetError(f"frame {frame.name or frame.index}: the oracle segmenter (--semantics oracle, "
                               f"--segmenter oracle) needs ground-truth labels; this sequence has none")
        gt = np.asarray(frame.labels).astype(np.int32)
        K = len(self._label_set)
        if gt.size and int(gt.max()) >= K:
            raise DatasetError(f"frame {frame.name or frame.index}: label {int(gt.max())} is outside the label set")
        rng = np.random.default_rng([_STREAM, self.seed, int(frame.index)])
        s = self.settings
        valid = gt > 0
        pred = gt.copy()
        blob_cls = np.zeros_like(gt)
        flagged = np.zeros(gt.shape, bool)
        n_valid = int(valid.sum())
        acc = float(np.clip(s.pixel_accuracy + rng.uniform(-1, 1) * s.accuracy_jitter, 0.0, 1.0))
        n_err = round((1.0 - acc) * n_valid)
        if n_err > 0 and s.independent:
            pred = self._independent_errors(gt, valid, n_err, rng)
        elif n_err > 0:
            score, flagged, blob_cls = self._error_scores(gt, frame.instances, rng)
            flat = np.where(valid, score, -np.inf).ravel()
            idx = np.argpartition(-flat, n_err - 1)[:n_err]
            err = np.zeros(gt.size, bool)
            err[idx] = True
            err = err.reshape(gt.shape)
            pred = self._wrong_labels(gt, err, flagged, blob_cls, rng)
        if s.soft:
            return self._soft_probs(gt, pred, rng)
        return self._paper_probs(gt, pred)

    # ------------------------------------------------------------------ error placement
    def _independent_errors(self, gt: np.ndarray, valid: np.ndarray, n_err: int,
                            rng: np.random.Generator) -> np.ndarray:
        """``gt`` with ``n_err`` uniformly chosen labelled pixels set to a uniformly random other real class."""
        K = len(self._label_set)
        idx = rng.choice(np.flatnonzero(valid.ravel()), size=n_err, replace=False)
        pred = gt.copy().ravel()
        shift = rng.integers(1, K - 1, n_err)  # 1..K-2 steps around the real classes 1..K-1: never the true one
        pred[idx] = 1 + (pred[idx] - 1 + shift) % (K - 1)
        return pred.reshape(gt.shape)

    def _error_scores(self, gt: np.ndarray, instances: np.ndarray | None, rng: np.random.Generator):
        """Per-pixel error score, the mask of objects confused this frame, and false-blob classes (0 = none)."""
        s = self.settings
        H, W = gt.shape
        edges = np.zeros(gt.shape, bool)
        edges[:, 1:] |= gt[:, 1:] != gt[:, :-1]
        edges[1:, :] |= gt[1:, :] != gt[:-1, :]
        dist = cv2.distanceTransform((~edges).astype(np.uint8), cv2.DIST_L2, 3)
        width = s.boundary_px * rng.uniform(0.6, 1.4)
        score = s.boundary_weight * np.exp(-dist / width)
        blotch = _smooth_field(rng, H, W, s.noise_cell_px)
        score += (s.noise_weight * 0.5) * blotch * self._difficulty[gt]
        # whole objects confused with a similar class: persistent propensity x per-frame draw
        K = len(self._label_set)
        region = gt if instances is None else np.where(instances > 0, instances.astype(np.int32) + K, gt)
        n_regions = int(region.max()) + 1
        prop = self._propensity[np.arange(n_regions) % len(self._propensity)]
        chosen = rng.random(n_regions) < s.flip_p * (0.25 + 1.5 * prop)
        flagged = chosen[region]
        score += flagged * (1.5 + 0.2 * blotch)
        # small false blobs of some other class
        blob_cls = np.zeros(gt.shape, np.int32)
        n_blobs = int(rng.poisson(s.blobs_per_frame))
        if n_blobs:
            canvas = np.zeros(gt.shape, np.uint8)
            r0, r1 = s.blob_radius_px
            for b in range(n_blobs):
                cx, cy = int(rng.integers(W)), int(rng.integers(H))
                ax = (int(rng.integers(r0, r1 + 1)), int(rng.integers(r0, r1 + 1)))
                cv2.ellipse(canvas, (cx, cy), ax, float(rng.uniform(0, 180)), 0, 360, b + 1, -1)
            classes = rng.integers(1, K, n_blobs + 1).astype(np.int32)
            classes[0] = 0
            blob_cls = classes[canvas]
            score += (blob_cls > 0) * 3.0
        return score, flagged, blob_cls

    def _wrong_labels(self, gt, err, flagged, blob_cls, rng) -> np.ndarray:
        """Predicted labels: ``gt`` except on ``err``, where a plausible wrong class is chosen.

        Boundary errors take the neighbouring class (the boundary moves), confused objects their partner
        class, blobs their own class; the choice is spatially coherent (patches, not salt and pepper).
        """
        K = len(self._label_set)
        H, W = gt.shape
        g16 = gt.astype(np.uint16)
        kernel = np.ones((7, 7), np.uint8)
        hi = cv2.dilate(g16, kernel).astype(np.int32)
        lo = cv2.erode(np.where(g16 == 0, np.uint16(65535), g16), kernel).astype(np.int32)
        neighbour = np.where(hi != gt, hi, np.where((lo != gt) & (lo < K), lo, 0))
        which = (_smooth_field(rng, H, W, 48) > 0.5).astype(np.int32)
        partner = self._partner[gt, which]
        choice = np.where(blob_cls > 0, blob_cls, np.where(flagged, partner, neighbour))
        choice = np.where(choice > 0, choice, partner)
        patch_cls = _patch_ints(rng, H, W, 40, 1, K)
        fallback = np.where(patch_cls == gt, 1 + patch_cls % (K - 1), patch_cls)
        choice = np.where((choice == gt) | (choice <= 0), fallback, choice)
        return np.where(err, choice, gt)

    # ------------------------------------------------------------------ probabilities
    def _lowest_others(self, K: int) -> np.ndarray:
        """For each class c: the k-1 lowest real class ids other than c (paper preset's top-k tail)."""
        out = np.full((K, max(self.k - 1, 0)), EMPTY_LABEL, np.int64)
        for c in range(K):
            others = [i for i in range(1, K) if i != c][: self.k - 1]
            out[c, : len(others)] = others
        return out

    def _paper_probs(self, gt: np.ndarray, pred: np.ndarray) -> TopKProbs:
        s = self.settings
        K = len(self._label_set)
        labels = np.full((*gt.shape, self.k), EMPTY_LABEL, np.uint16)
        probs = np.zeros((*gt.shape, self.k), np.float32)
        labels[..., 0] = pred
        probs[..., 0] = s.true_prob
        if self.k > 1:
            tail = self._paper_others[pred]
            labels[..., 1:] = tail
            probs[..., 1:] = np.where(tail != EMPTY_LABEL, (1.0 - s.true_prob) / max(K - 2, 1), 0.0)
        return self._void(gt, labels, probs)

    def _soft_probs(self, gt: np.ndarray, pred: np.ndarray, rng: np.random.Generator) -> TopKProbs:
        s = self.settings
        H, W = gt.shape
        wrong = pred != gt
        lo, hi = s.conf_range
        # confidence: smooth over the image with per-pixel jitter, lower on wrong pixels
        smooth = _smooth_field(rng, H, W, 32)
        jitter = rng.random((H, W), dtype=np.float32)
        t = 0.425 + 0.1375 * smooth + 0.3 * jitter - 0.35 * wrong
        conf = lo + (hi - lo) * np.clip(t, 0.0, 1.0)
        # second choice: the true class for most wrong pixels, a confusable (or some other) class otherwise
        random_cls = _patch_ints(rng, H, W, 24, 1, len(self._label_set))
        partner = self._partner[:, 0][pred]
        second = np.where(partner > 0, partner, random_cls)
        second = np.where(wrong & (jitter < s.second_is_true_p), gt, second)
        second = np.where(second == pred, self._next_class[pred], second)
        third = np.where((random_cls == pred) | (random_cls == second), self._next_class[np.maximum(pred, second)],
                         random_cls)
        third = np.where((third == pred) | (third == second), 0, third)
        p2 = (1.0 - conf) * (0.45 + 0.7 * np.abs(jitter - 0.5))
        p3 = (1.0 - conf - p2) * (0.3 + 0.3 * jitter)
        labels = np.stack([pred, second, third], -1)[..., : self.k].astype(np.uint16)
        probs = np.stack([conf, p2, p3], -1)[..., : self.k].astype(np.float32)
        if self.k > 3:
            pad = ((0, 0), (0, 0), (0, self.k - 3))
            labels = np.pad(labels, pad, constant_values=EMPTY_LABEL)
            probs = np.pad(probs, pad)
        empty = labels == 0
        labels[empty] = EMPTY_LABEL
        probs[empty] = 0.0
        return self._void(gt, labels, probs)

    def _void(self, gt: np.ndarray, labels: np.ndarray, probs: np.ndarray) -> TopKProbs:
        """Pixels without ground truth (label 0) get "unknown" with probability 1."""
        void = gt == 0
        if void.any():
            labels[void] = EMPTY_LABEL
            probs[void] = 0.0
            labels[void, 0] = 0
            probs[void, 0] = 1.0
        return TopKProbs(labels, probs)


def _smooth_field(rng: np.random.Generator, H: int, W: int, cell: int) -> np.ndarray:
    """(H, W) float32 smooth random field, about unit variance, with features ``cell`` pixels wide."""
    small = rng.standard_normal((max(2, H // cell), max(2, W // cell))).astype(np.float32)
    return cv2.resize(small, (W, H), interpolation=cv2.INTER_CUBIC)


def _patch_ints(rng: np.random.Generator, H: int, W: int, cell: int, lo: int, hi: int) -> np.ndarray:
    """(H, W) int32 random integers in [lo, hi), constant over patches about ``cell`` pixels wide."""
    small = rng.integers(lo, hi, (max(2, H // cell), max(2, W // cell))).astype(np.uint16)
    return cv2.resize(small, (W, H), interpolation=cv2.INTER_NEAREST).astype(np.int32)


def measured_accuracy(segmenter, frames: Iterable[Frame]) -> float:
    """Pixel accuracy (argmax == ground truth over pixels with a label > 0) of ``segmenter`` on ``frames``."""
    correct = total = 0
    for frame in frames:
        if frame.labels is None:
            raise DatasetError(f"frame {frame.name or frame.index} has no ground-truth labels")
        pred = segmenter.segment(frame).argmax()
        valid = frame.labels > 0
        correct += int((pred[valid] == frame.labels[valid]).sum())
        total += int(valid.sum())
    if total == 0:
        raise DatasetError("no labelled pixels to measure accuracy on")
    return correct / total
