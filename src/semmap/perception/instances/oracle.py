"""Oracle instances: the simulator's instance images turned into detector output, with controlled errors.

A real instance segmenter (the paper's Mask R-CNN) misses objects, splits one object into two masks, merges
neighbours of one class into one mask, erodes masks or lets them bleed over the object's outline, calls an object
by a similar class (the paper's teddy bear seen as a person) and reports things that are not there. The presets:

- ``exact``: every instance with at least ``min_pixels`` pixels, its true class, score 1, no errors;
- ``maskrcnn-like`` (default): per frame and object 5 % missed, 2 % split, 3 % merged with a touching neighbour of
  its class, outlines moved by up to 2 px either way, 5 % a similar class (scaled by a persistent per-object
  propensity, so some objects are confused often), 0.2 false detections per frame;
- ``noisy``: about three times as many errors and 4 px outlines.

Everything is drawn from a generator seeded by ``(seed, frame.index)``, so results do not depend on call order;
the per-object confusion propensity is fixed per seed.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace

import cv2
import numpy as np

from semmap.errors import ConfigError, DatasetError
from semmap.perception.instances.base import thing_classes
from semmap.perception.oracle import CONFUSIONS
from semmap.types import Frame, Instances, LabelSet, TopKProbs

_STREAM = 0x1A57


@dataclass(frozen=True)
class InstanceErrors:
    """Error model of :class:`OracleInstances`; probabilities are per frame and object unless noted."""

    min_pixels: int = 150  #: instances smaller than this are not reported (a detector misses tiny things)
    miss_p: float = 0.05
    split_p: float = 0.02
    merge_p: float = 0.03  #: chance that an object and a touching neighbour of its class come as one mask
    boundary_px: int = 2  #: each mask is eroded or dilated by up to this many pixels (uniform, either way)
    wrong_class_p: float = 0.05  #: scaled by the object's persistent propensity (0.25x to 1.75x)
    false_per_frame: float = 0.2  #: expected spurious detections per frame (blobs of a random object class)
    false_radius_px: tuple[int, int] = (8, 30)

    def __post_init__(self) -> None:
        for name in ("miss_p", "split_p", "merge_p", "wrong_class_p"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ConfigError(f"instance error {name} must be in [0, 1], got {getattr(self, name)}")
        if self.min_pixels < 1 or self.boundary_px < 0 or self.false_per_frame < 0:
            raise ConfigError("instance errors: min_pixels >= 1, boundary_px >= 0 and false_per_frame >= 0")


INSTANCE_PRESETS: dict[str, InstanceErrors] = {
    "exact": InstanceErrors(miss_p=0.0, split_p=0.0, merge_p=0.0, boundary_px=0, wrong_class_p=0.0,
                            false_per_frame=0.0),
    "maskrcnn-like": InstanceErrors(),
    "noisy": InstanceErrors(miss_p=0.15, split_p=0.06, merge_p=0.08, boundary_px=4, wrong_class_p=0.12,
                            false_per_frame=0.6),
}


class OracleInstances:
    """:class:`~semmap.perception.instances.InstanceSource` made from ground-truth instance and label images."""

    name = "oracle"
    needs_semantics = False

    def __init__(self, label_set: LabelSet, *, preset: str = "maskrcnn-like", seed: int = 0, **overrides) -> None:
        if preset not in INSTANCE_PRESETS:
            raise ConfigError(f"unknown instance error preset {preset!r}; choose one of {', '.join(INSTANCE_PRESETS)}")
        known = {f.name for f in fields(InstanceErrors)}
        if set(overrides) - known:
            raise ConfigError(f"unknown instance error setting(s) {', '.join(sorted(set(overrides) - known))}")
        self._label_set = label_set
        self.preset = preset
        self.errors = replace(INSTANCE_PRESETS[preset], **overrides)
        self.seed = int(seed)
        K = len(label_set)
        things = thing_classes(label_set)
        self._things = np.flatnonzero(things).astype(np.int32)
        self._partner = np.arange(K, dtype=np.int32)  # the object class an object is mistaken for (itself: none)
        for cid, name in enumerate(label_set.names):
            partners = [label_set.names.index(p) for p in CONFUSIONS.get(name, ())
                        if p in label_set.names and things[label_set.names.index(p)]]
            if partners:
                self._partner[cid] = partners[0]
        self._propensity = np.random.default_rng([_STREAM, self.seed, 1]).random(1 << 16).astype(np.float32)

    @property
    def label_set(self) -> LabelSet:
        return self._label_set

    def detect(self, frame: Frame, semantics: TopKProbs | None = None) -> Instances:
        """Detections of ``frame``'s ground-truth instances after the error model (``semantics`` is not used)."""
        where = f"frame {frame.name or frame.index}"
        if frame.instances is None or frame.labels is None:
            raise DatasetError(f"{where}: oracle instances need the frame's instance and label images (simulator)")
        rng = np.random.default_rng([_STREAM, self.seed, int(frame.index)])
        e = self.errors
        gt, ids, classes = _compact(frame.instances, frame.labels, len(self._label_set))
        n = len(classes)
        keep = np.ones(n, bool)
        keep &= rng.random(n) >= e.miss_p
        ids, classes, keep = self._merge(ids, classes, keep, rng)
        ids = np.where(keep[np.maximum(ids, 1) - 1] & (ids > 0), ids, 0) if n else np.zeros_like(ids)  # none in view
        ids = self._move_outlines(ids, n, rng)
        ids, classes, gt = self._split(ids, classes, gt, rng)
        scores = rng.uniform(0.7, 1.0, len(classes)).astype(np.float32) if e.wrong_class_p or e.miss_p else \
            np.ones(len(classes), np.float32)
        wrong = rng.random(len(classes)) < e.wrong_class_p * (0.25 + 1.5 * self._propensity[gt % (1 << 16)])
        wrong &= self._partner[classes] != classes
        classes = np.where(wrong, self._partner[classes], classes)
        scores[wrong] = rng.uniform(0.5, 0.8, int(wrong.sum()))
        ids, classes, scores = self._false_detections(ids, classes, scores, rng)
        counts = np.bincount(ids.ravel(), minlength=len(classes) + 1)[1:]
        small = counts < e.min_pixels
        if small.any():
            renumber = np.zeros(len(classes) + 1, np.int32)
            renumber[1:][~small] = np.arange(1, int((~small).sum()) + 1)
            ids = renumber[ids]
            classes, scores = classes[~small], scores[~small]
        return Instances.from_id_image(ids, classes, scores)

    # ------------------------------------------------------------------ errors
    def _merge(self, ids: np.ndarray, classes: np.ndarray, keep: np.ndarray, rng: np.random.Generator):
        """Touching instances of one class merged into one mask with probability ``merge_p`` per pair."""
        if self.errors.merge_p <= 0 or len(classes) < 2:
            return ids, classes, keep
        pairs = _touching_pairs(ids)
        if len(pairs) == 0:
            return ids, classes, keep
        same = classes[pairs[:, 0] - 1] == classes[pairs[:, 1] - 1]
        pairs = pairs[same & (rng.random(len(pairs)) < self.errors.merge_p)]
        if len(pairs) == 0:
            return ids, classes, keep
        root = np.arange(len(classes) + 1)
        for a, b in pairs:  # a handful of pairs per frame: union-find by hand
            ra, rb = _find(root, a), _find(root, b)
            if ra != rb:
                root[max(ra, rb)] = min(ra, rb)
        final = np.array([_find(root, i) for i in range(len(root))])
        merged_keep = keep.copy()
        for i in range(1, len(root)):
            if final[i] != i:
                merged_keep[final[i] - 1] |= keep[i - 1]  # the merged mask is reported if either part was
                merged_keep[i - 1] = False
        return final.astype(np.int32)[ids], classes, merged_keep

    def _move_outlines(self, ids: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
        """Each mask eroded or dilated (into unclaimed pixels) by a random number of pixels up to ``boundary_px``."""
        r_max = self.errors.boundary_px
        if r_max == 0 or n == 0 or not ids.any():
            return ids
        radius = rng.integers(-r_max, r_max + 1, n + 1)
        radius[0] = 0
        edges = np.zeros(ids.shape, bool)
        edges[:, 1:] |= ids[:, 1:] != ids[:, :-1]
        edges[:, :-1] |= ids[:, 1:] != ids[:, :-1]
        edges[1:, :] |= ids[1:, :] != ids[:-1, :]
        edges[:-1, :] |= ids[1:, :] != ids[:-1, :]
        inside = cv2.distanceTransform((~(edges & (ids > 0))).astype(np.uint8), cv2.DIST_L2, 3)
        out = np.where((ids > 0) & (inside < -radius[ids]), 0, ids)  # erosion: pixels near the own outline go
        grow = radius > 0
        if grow.any():
            dist, nearest = cv2.distanceTransformWithLabels((ids == 0).astype(np.uint8), cv2.DIST_L2, 3,
                                                            labelType=cv2.DIST_LABEL_PIXEL)
            # DIST_LABEL_PIXEL numbers the source (object) pixels 1..L in row-major order
            owner = np.concatenate([[0], ids[ids != 0]]).astype(np.int32)[nearest]
            bleed = (ids == 0) & (owner > 0) & (dist <= radius[owner]) & grow[owner]
            out = np.where(bleed, owner, out)
        return out.astype(np.int32)

    def _split(self, ids: np.ndarray, classes: np.ndarray, gt: np.ndarray, rng: np.random.Generator):
        """Masks cut in two along a random line through their centre with probability ``split_p``."""
        n = len(classes)
        chosen = np.flatnonzero(rng.random(n) < self.errors.split_p) + 1
        angles = rng.uniform(0, np.pi, len(chosen))
        if len(chosen) == 0:
            return ids, classes, gt
        ids = ids.copy()
        new_classes, new_gt = list(classes), list(gt)
        for k, angle in zip(chosen, angles, strict=True):
            v, u = np.nonzero(ids == k)
            if len(v) < 2 * self.errors.min_pixels:
                continue
            side = (u - u.mean()) * np.cos(angle) + (v - v.mean()) * np.sin(angle) > 0
            new_classes.append(classes[k - 1])
            new_gt.append(gt[k - 1])
            ids[v[side], u[side]] = len(new_classes)
        return ids, np.asarray(new_classes, np.int32), np.asarray(new_gt, np.int64)

    def _false_detections(self, ids: np.ndarray, classes: np.ndarray, scores: np.ndarray,
                          rng: np.random.Generator):
        """Spurious blobs of a random object class on unclaimed pixels."""
        n_false = int(rng.poisson(self.errors.false_per_frame)) if self.errors.false_per_frame > 0 else 0
        if n_false == 0 or len(self._things) == 0:
            return ids, classes, scores
        H, W = ids.shape
        ids = ids.copy()
        r0, r1 = self.errors.false_radius_px
        new_classes, new_scores = list(classes), list(scores)
        for _ in range(n_false):
            canvas = np.zeros((H, W), np.uint8)
            axes = (int(rng.integers(r0, r1 + 1)), int(rng.integers(r0, r1 + 1)))
            cv2.ellipse(canvas, (int(rng.integers(W)), int(rng.integers(H))), axes, float(rng.uniform(0, 180)),
                        0, 360, 1, -1)
            new_classes.append(int(rng.choice(self._things)))
            new_scores.append(float(rng.uniform(0.5, 0.7)))
            ids[(canvas > 0) & (ids == 0)] = len(new_classes)
        return ids, np.asarray(new_classes, np.int32), np.asarray(new_scores, np.float32)


def _compact(instances: np.ndarray, labels: np.ndarray, num_classes: int):
    """(ground-truth id per detection, id image numbered 1..n, class per detection) of an instance image."""
    inst = np.asarray(instances).astype(np.int64)
    if inst.size and int(inst.min()) < 0:
        raise DatasetError("instance images must hold non-negative ids")
    present = np.bincount(inst.ravel()) > 0  # ids are small: a lookup table beats sorting 300k pixels
    present[0] = True
    uniq = np.flatnonzero(present)
    lut = np.zeros(len(present), np.int32)
    lut[uniq] = np.arange(len(uniq), dtype=np.int32)
    inv = lut[inst]
    n = len(uniq) - 1
    lab = np.minimum(np.asarray(labels).astype(np.int64), num_classes - 1)
    votes = np.bincount(inv.ravel().astype(np.int64) * num_classes + lab.ravel(),
                        minlength=(n + 1) * num_classes).reshape(n + 1, num_classes)
    classes = votes[1:].argmax(axis=1).astype(np.int32)
    return uniq[1:], inv, classes


def _touching_pairs(ids: np.ndarray) -> np.ndarray:
    """(P, 2) int32 distinct pairs ``a < b`` of non-zero ids that touch horizontally or vertically."""
    a = np.concatenate([ids[:, 1:].ravel(), ids[1:, :].ravel()])
    b = np.concatenate([ids[:, :-1].ravel(), ids[:-1, :].ravel()])
    sel = (a != b) & (a > 0) & (b > 0)
    if not sel.any():
        return np.zeros((0, 2), np.int32)
    lo, hi = np.minimum(a[sel], b[sel]), np.maximum(a[sel], b[sel])
    pairs = np.unique(lo.astype(np.int64) << 32 | hi.astype(np.int64))
    return np.column_stack([pairs >> 32, pairs & 0xFFFFFFFF]).astype(np.int32)


def _find(root: np.ndarray, i: int) -> int:
    while root[i] != i:
        root[i] = root[root[i]]
        i = root[i]
    return int(i)
