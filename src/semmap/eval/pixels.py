"""Map-at-pixel evaluation: does the fused map label a pixel better than the network that built it?

For each evaluated frame (every ``every``-th), each pixel with a depth and a true label is back-projected with the
frame's pose; the map's label there (:meth:`SemanticMap.class_at`: the occupied voxel holding the point, the point
map's point in its cell) is scored against the true label on exactly the pixels where both the map and the network
give a label, beside the network's own label at the same pixels: the comparison SemanticFusion makes, free of the
pixel-versus-voxel weighting that makes a 2D and a 3D mIoU incomparable.  Two variants: the final map, and the
causal one (the map as it stood when the frame arrived, before the frame was fused).  :func:`fusion_ceiling` says
how much any per-voxel rule could gain with a network: a voxel whose views mostly give a wrong class cannot be
fixed by fusing them.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from semmap.eval.semantic import confusion, scores
from semmap.geometry import DEFAULT_MAX_DEPTH, DEFAULT_MIN_DEPTH, backproject_world
from semmap.keys import coords_to_keys, pack_keys
from semmap.maps.base import SemanticMap
from semmap.types import EMPTY_LABEL, Frame, LabelSet, TopKProbs

#: Every how many mapped frames one is evaluated (the field's usual sampling of a sequence).
EVERY = 10
#: A run keeps every n-th pixel row and column of its evaluated frames until the map is final (memory: 16 bytes a
#: kept pixel); ``semmap eval-map`` streams frames and scores every pixel.
RUN_PIXEL_STRIDE = 2
_EMPTY = int(EMPTY_LABEL)


@dataclass
class PixelSample:
    """One evaluated frame's pixels with a depth and a true label: world points (in the map's frame), true labels,
    the network's top labels (EMPTY_LABEL where it gave none) and each map's labels when the frame arrived."""

    points: np.ndarray  # (N, 3) float32
    gt: np.ndarray  # (N,) uint16, never 0
    net: np.ndarray  # (N,) uint16
    causal: dict[str, np.ndarray] = field(default_factory=dict)  # map kind -> (N,) uint16


def frame_sample(frame: Frame, T_world_cam: np.ndarray, semantics: TopKProbs | None, *,
                 min_depth: float = DEFAULT_MIN_DEPTH, max_depth: float = DEFAULT_MAX_DEPTH,
                 stride: int = 1) -> PixelSample | None:
    """The pixels of ``frame`` to score (valid depth, a true label other than 0 = unknown), seen from
    ``T_world_cam``, with the network's top label from ``semantics`` (H, W, k); None for a frame without labels."""
    if frame.labels is None:
        return None
    points, pixels = backproject_world(frame.depth, frame.intrinsics, T_world_cam, min_depth=min_depth,
                                       max_depth=max_depth, stride=stride)
    gt = np.take(frame.labels.reshape(-1), pixels).astype(np.uint16)
    if semantics is not None:
        net = np.take(semantics.labels[..., 0].reshape(-1), pixels).astype(np.uint16)
    else:
        net = np.full(len(pixels), EMPTY_LABEL, np.uint16)
    keep = gt != 0
    return PixelSample(np.ascontiguousarray(points[keep], np.float32), gt[keep], net[keep])


def map_classes_at(m: SemanticMap, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The map's most probable class (uint16, EMPTY_LABEL where it has none) and its probability (float32) at
    each (N, 3) point: the one lookup the map-at-pixel scores and the pseudo-labels of ``semmap adapt`` share."""
    if len(points) == 0:
        return np.zeros(0, np.uint16), np.zeros(0, np.float32)
    labels, confidence = m.class_at(points)
    return np.asarray(labels, np.uint16), np.asarray(confidence, np.float32)


def map_labels_at(m: SemanticMap, points: np.ndarray) -> np.ndarray:
    """The map's most probable class at each (N, 3) point (EMPTY_LABEL where it has none), uint16."""
    return map_classes_at(m, points)[0]


@dataclass(frozen=True)
class MapView:
    """A map rendered into one frame: at each kept pixel (flat index into the frame, every ``stride``-th row and
    column with a depth in range) its 3D point, the map's class there (EMPTY_LABEL: none) and that class's
    probability."""

    shape: tuple[int, int]  # (H, W) of the frame
    stride: int
    pixels: np.ndarray  # (N,) int64 flat indices v * W + u
    points: np.ndarray  # (N, 3) float32 world points
    labels: np.ndarray  # (N,) uint16
    confidence: np.ndarray  # (N,) float32

    def image(self, values: np.ndarray, fill, dtype) -> np.ndarray:
        """(ceil(H / stride), ceil(W / stride)) image of per-pixel ``values`` (N,), ``fill`` elsewhere."""
        h, w = self.shape
        s = self.stride
        out = np.full(((h + s - 1) // s, (w + s - 1) // s), fill, dtype)
        v, u = np.divmod(self.pixels, w)
        out[v // s, u // s] = values
        return out


def map_view(m: SemanticMap, frame: Frame, T_world_cam: np.ndarray, *, min_depth: float = DEFAULT_MIN_DEPTH,
             max_depth: float = DEFAULT_MAX_DEPTH, stride: int = 1) -> MapView:
    """The map's class and confidence at every (``stride``-th) pixel's 3D point of ``frame`` seen from
    ``T_world_cam``: the lookup of the map-at-pixel scores, for every pixel with a depth in range."""
    points, pixels = backproject_world(frame.depth, frame.intrinsics, T_world_cam, min_depth=min_depth,
                                       max_depth=max_depth, stride=stride)
    labels, confidence = map_classes_at(m, points)
    return MapView(frame.depth.shape, int(stride), pixels, points, labels, confidence)


@dataclass
class PixelScores:
    """Confusions of the map and of the network on the same pixels, accumulated over frames, and coverage."""

    num_classes: int
    eligible: int = 0  # pixels with a depth, a true label (and a network label, when there is a network)
    scored: int = 0  # of them, the pixels where the map gives a label
    frames: int = 0
    has_network: bool = False  # a frame came with the network's labels
    conf_map: np.ndarray = field(init=False)  # (K, K) rows = truth, columns = the map's label
    conf_net: np.ndarray = field(init=False)  # (K, K) the network's, on the same pixels

    def __post_init__(self) -> None:
        self.conf_map = np.zeros((self.num_classes, self.num_classes), np.int64)
        self.conf_net = np.zeros((self.num_classes, self.num_classes), np.int64)

    def add(self, gt: np.ndarray, net: np.ndarray | None, map_labels: np.ndarray) -> None:
        """One frame's pixels: true labels, the network's (None: no network) and the map's (EMPTY_LABEL = none)."""
        gt = np.asarray(gt)
        eligible = np.ones(len(gt), bool) if net is None else np.asarray(net) != _EMPTY
        both = eligible & (np.asarray(map_labels) != _EMPTY)
        self.conf_map += confusion(np.asarray(map_labels)[both], gt[both], self.num_classes)
        if net is not None:
            self.conf_net += confusion(np.asarray(net)[both], gt[both], self.num_classes)
            self.has_network = True
        self.eligible += int(eligible.sum())
        self.scored += int(both.sum())
        self.frames += 1

    def per_class(self, label_set: LabelSet) -> dict:
        """IoU per class of the map (``pixel_per_class_iou_map``) and the network (``..._network``) at the same
        pixels, classes present in the truth there."""
        out = {"pixel_per_class_iou_map": scores(self.conf_map).per_class(label_set)}
        if self.has_network:
            out["pixel_per_class_iou_network"] = scores(self.conf_net).per_class(label_set)
        return out

    def summary(self, suffix: str = "") -> dict:
        """``pixel_miou_map``, ``pixel_miou_network``, accuracy and MPA of both, their ``pixel_gain`` (map minus
        network mIoU) and ``pixel_coverage``; keys end in ``suffix`` (``_causal``)."""
        out: dict = {}
        m = scores(self.conf_map)
        out.update({f"pixel_miou_map{suffix}": _r(m.miou), f"pixel_accuracy_map{suffix}": _r(m.accuracy),
                    f"pixel_mpa_map{suffix}": _r(m.mpa)})
        if self.has_network:
            n = scores(self.conf_net)
            out.update({f"pixel_miou_network{suffix}": _r(n.miou), f"pixel_accuracy_network{suffix}": _r(n.accuracy),
                        f"pixel_mpa_network{suffix}": _r(n.mpa), f"pixel_gain{suffix}": _r(m.miou - n.miou)})
        out[f"pixel_coverage{suffix}"] = _r(self.scored / self.eligible) if self.eligible else float("nan")
        out[f"pixels_scored{suffix}"] = self.scored
        return out


def _r(v: float) -> float:
    return round(float(v), 4)


def score_samples(samples: Sequence[PixelSample], m: SemanticMap, num_classes: int, *,
                  causal: bool = False) -> PixelScores:
    """The map ``m`` (final) or, with ``causal``, its labels kept when each frame arrived, on the samples' pixels
    (beside the network's where any sample has a network label)."""
    acc = PixelScores(num_classes)
    kind = m.kind.value
    network = any((s.net != _EMPTY).any() for s in samples)
    for s in samples:
        labels = s.causal[kind] if causal else map_labels_at(m, s.points)
        acc.add(s.gt, s.net if network else None, labels)
    return acc


@dataclass
class PixelRecord:
    """What a run keeps for the map-at-pixel scores: every ``every``-th mapped frame's pixels (every ``stride``-th
    row and column) with the network's labels and each map's labels when the frame arrived (the causal variant)."""

    every: int = EVERY
    stride: int = RUN_PIXEL_STRIDE
    samples: list[PixelSample] = field(default_factory=list)

    def due(self, mapped: int) -> bool:
        """Whether the frame after ``mapped`` mapped frames is evaluated."""
        return self.every > 0 and mapped % self.every == 0

    def add(self, frame: Frame, T_world_cam: np.ndarray, semantics: TopKProbs | None, maps: Sequence[SemanticMap],
            *, min_depth: float, max_depth: float) -> None:
        """Keep ``frame``'s pixels and every labelled map's labels there now, before the frame is fused."""
        s = frame_sample(frame, T_world_cam, semantics, min_depth=min_depth, max_depth=max_depth, stride=self.stride)
        if s is None:
            return
        s.causal = {m.kind.value: map_labels_at(m, s.points) for m in maps if m.label_set is not None}
        self.samples.append(s)

    def report(self, m: SemanticMap) -> dict:
        """The map-at-pixel scores of ``m``, final and causal, with the fusion ceiling; empty without samples."""
        if not self.samples or m.label_set is None or m.kind.value not in self.samples[0].causal:
            return {}
        k = len(m.label_set)
        final = score_samples(self.samples, m, k)
        out = {"pixel_frames": len(self.samples), "pixel_every": self.every, "pixel_stride": self.stride,
               **final.summary(), **score_samples(self.samples, m, k, causal=True).summary("_causal"),
               **final.per_class(m.label_set)}
        if any((s.net != _EMPTY).any() for s in self.samples):
            out.update(fusion_ceiling(np.concatenate([s.points for s in self.samples]),
                                      np.concatenate([s.gt for s in self.samples]),
                                      np.concatenate([s.net for s in self.samples]), m.resolution))
        return out

    def state(self) -> dict[str, np.ndarray]:
        """A checkpoint's samples as flat arrays (their sizes split them again)."""
        kinds = sorted(self.samples[0].causal) if self.samples else []
        out = {"sizes": np.array([len(s.gt) for s in self.samples], np.int64),
               "xyz": _cat([s.points for s in self.samples], (0, 3), np.float32),
               "truth": _cat([s.gt for s in self.samples], (0,), np.uint16),
               "net": _cat([s.net for s in self.samples], (0,), np.uint16)}
        out.update({f"causal/{k}": _cat([s.causal[k] for s in self.samples], (0,), np.uint16) for k in kinds})
        return out

    def restore(self, arrays: dict[str, np.ndarray]) -> None:
        """Continue from :meth:`state`."""
        cuts = np.cumsum(np.asarray(arrays["sizes"], np.int64))[:-1]
        kinds = [k.removeprefix("causal/") for k in arrays if k.startswith("causal/")]
        split = {name: np.split(np.asarray(arrays[name]), cuts) for name in ("xyz", "truth", "net")}
        causal = {k: np.split(np.asarray(arrays[f"causal/{k}"]), cuts) for k in kinds}
        self.samples = [PixelSample(split["xyz"][i], split["truth"][i], split["net"][i],
                                    {k: causal[k][i] for k in kinds}) for i in range(len(arrays["sizes"]))]


def _cat(parts: list[np.ndarray], empty_shape: tuple[int, ...], dtype) -> np.ndarray:
    return np.concatenate(parts) if parts else np.zeros(empty_shape, dtype)


def fusion_ceiling(points: np.ndarray, gt: np.ndarray, net: np.ndarray, resolution: float) -> dict:
    """What any per-voxel rule could get right with this network: per voxel (at ``resolution``) seen by labelled
    pixels, the true class (the plurality of its pixels' true labels) against the plurality of the network's labels
    over all views of it.  ``ceiling_voxel_accuracy`` is the share of voxels the plurality gets right, and
    ``unreachable_share`` the share whose true class is not even among the network's labels there (no rule can
    pick it)."""
    net = np.asarray(net)
    has = net != _EMPTY
    points, gt, net = np.asarray(points)[has], np.asarray(gt)[has], net[has]
    if len(points) == 0:
        return {"ceiling_voxels": 0}
    voxel = np.unique(pack_keys(coords_to_keys(points, resolution)), return_inverse=True)[1]
    n_vox = int(voxel.max()) + 1
    k = int(max(gt.max(), net.max())) + 1
    true = _plurality(voxel, gt.astype(np.int64), n_vox, k)
    votes = np.bincount(voxel * k + net.astype(np.int64), minlength=n_vox * k).reshape(n_vox, k)
    top = np.argmax(votes, axis=1)  # ties: the lower class id
    reachable = votes[np.arange(n_vox), true] > 0
    return {"ceiling_voxels": n_vox, "ceiling_voxel_accuracy": _r((top == true).mean()),
            "unreachable_share": _r(1.0 - reachable.mean()), "plurality_wrong_share": _r((top != true).mean())}


def _plurality(voxel: np.ndarray, labels: np.ndarray, n_vox: int, k: int) -> np.ndarray:
    counts = np.bincount(voxel * k + labels, minlength=n_vox * k).reshape(n_vox, k)
    return np.argmax(counts, axis=1)
