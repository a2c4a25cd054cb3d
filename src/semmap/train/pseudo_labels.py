"""Pseudo-labels: a finished map rendered back into the frames it was built from, as training labels for the
network that built it (``semmap adapt``; Frey et al., RA-L 2022, with a voxel map).

Each pixel with a depth takes the map's most probable class and its probability at the pixel's 3D point, the
lookup of the map-at-pixel scores (:func:`semmap.eval.pixels.map_view`). A pixel teaches nothing (label 0, which
training ignores) where the map is unsure of it:

* low confidence: the class's fused probability is below ``min_confidence``;
* too few views: fewer than ``min_views`` of the frames saw the voxel (one view is the network's own guess again);
* disagreement with the geometry: the pixel lies within ``edge_px`` of a depth jump (more than ``edge_jump_m``, or
  ``edge_jump_share`` of the depth) or of a hole, where its voxel may hold two surfaces and a small pose or
  depth error moves the pixel onto the other one; or the map has no occupied voxel at the point;
* a confident network: the network about to be adapted gives the pixel another class with probability at least
  ``network_confidence`` (where it is that sure and the map disagrees, the map is more often wrong: a voxel
  larger than a thin object, a chair's voxels reaching into the table above it; docs/EXPERIMENTS.md).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from semmap.eval.pixels import map_view
from semmap.eval.semantic import confusion
from semmap.geometry import DEFAULT_MAX_DEPTH, DEFAULT_MIN_DEPTH, backproject_world
from semmap.keys import coords_to_keys, index_in, pack_keys
from semmap.maps.base import SemanticMap
from semmap.train.class_weights import IGNORE
from semmap.types import EMPTY_LABEL, Frame

#: Why a pixel with a depth teaches nothing, in the order the masks are applied.
REASONS = ("no_class", "low_confidence", "few_views", "depth_edge", "confident_network")


@dataclass(frozen=True)
class MaskSettings:
    """When the map is too unsure of a pixel to teach it."""

    min_confidence: float = 0.5
    min_views: int = 3
    edge_px: int = 0  #: 0: the pixels on either side of a jump or next to a hole only
    edge_jump_m: float = 0.1
    edge_jump_share: float = 0.05
    network_confidence: float | None = 0.7  #: None: the network's own labels never veto the map's

    def to_dict(self) -> dict:
        return {"min_confidence": self.min_confidence, "min_views": self.min_views, "edge_px": self.edge_px,
                "edge_jump_m": self.edge_jump_m, "edge_jump_share": self.edge_jump_share,
                "network_confidence": self.network_confidence}


class ViewCounter:
    """How many frames saw each voxel (at the map's resolution): one count per frame however many of its pixels
    fall in the voxel."""

    def __init__(self, resolution: float) -> None:
        self.resolution = float(resolution)
        self._parts: list[np.ndarray] = []
        self._keys = np.zeros(0, np.int64)
        self._counts = np.zeros(0, np.int64)

    def add(self, frame: Frame, T_world_cam: np.ndarray, *, stride: int = 1, min_depth: float = DEFAULT_MIN_DEPTH,
            max_depth: float = DEFAULT_MAX_DEPTH) -> None:
        """Count the voxels of one frame's (every ``stride``-th) pixels with a depth in range."""
        points, _ = backproject_world(frame.depth, frame.intrinsics, T_world_cam, min_depth=min_depth,
                                      max_depth=max_depth, stride=stride)
        self._parts.append(np.unique(pack_keys(coords_to_keys(points, self.resolution))))
        if len(self._parts) >= 64:  # fold in now and then: memory stays at the voxels seen, not the frames
            self._fold()

    def _fold(self) -> None:
        if not self._parts:
            return
        keys = np.concatenate([np.repeat(self._keys, self._counts), *self._parts])
        self._keys, self._counts = np.unique(keys, return_counts=True)
        self._parts = []

    def counts_at(self, points: np.ndarray) -> np.ndarray:
        """(N,) frames that saw the voxel holding each (N, 3) point (0 for a voxel no frame saw)."""
        self._fold()
        pos = index_in(self._keys, pack_keys(coords_to_keys(points, self.resolution)))
        return np.where(pos >= 0, self._counts[np.maximum(pos, 0)], 0)


def depth_edges(depth: np.ndarray, *, radius: int, jump_m: float, jump_share: float) -> np.ndarray:
    """(H, W) bool: pixels within ``radius`` pixels of a depth jump between 4-neighbours larger than
    max(``jump_m``, ``jump_share`` x the nearer depth), or of a pixel without depth (0 or not finite)."""
    d = np.nan_to_num(np.asarray(depth, np.float32), nan=0.0, posinf=0.0, neginf=0.0)
    valid = d > 0
    edge = np.zeros(d.shape, bool)
    for a, b, sl_a, sl_b in ((d[:, 1:], d[:, :-1], (slice(None), slice(1, None)), (slice(None), slice(None, -1))),
                             (d[1:, :], d[:-1, :], (slice(1, None), slice(None)), (slice(None, -1), slice(None)))):
        va, vb = valid[sl_a], valid[sl_b]
        near = np.minimum(a, b)
        jump = (va != vb) | (va & vb & (np.abs(a - b) > np.maximum(jump_m, jump_share * near)))
        edge[sl_a] |= jump
        edge[sl_b] |= jump
    if radius > 0 and edge.any():
        kernel = np.ones((2 * radius + 1, 2 * radius + 1), np.uint8)
        edge = cv2.dilate(edge.astype(np.uint8), kernel) > 0
    return edge


@dataclass
class PseudoLabels:
    """One frame's pseudo-labels on its rendering grid (every ``stride``-th row and column): ``labels`` (0 = teaches
    nothing), the map's class before masking (``map_labels``, 0 where none) and its probability, and how many
    pixels with a depth each mask removed."""

    labels: np.ndarray  # (h, w) uint16
    map_labels: np.ndarray  # (h, w) uint16
    confidence: np.ndarray  # (h, w) float32
    stride: int
    with_depth: int = 0
    removed: dict[str, int] = field(default_factory=dict)

    @property
    def kept(self) -> int:
        return int((self.labels != IGNORE).sum())


def pseudo_labels(m: SemanticMap, frame: Frame, T_world_cam: np.ndarray, views: ViewCounter | None,
                  settings: MaskSettings = MaskSettings(), *, stride: int = 1, class_lut: np.ndarray | None = None,
                  min_depth: float = DEFAULT_MIN_DEPTH, max_depth: float = DEFAULT_MAX_DEPTH) -> PseudoLabels:
    """The map ``m`` rendered into ``frame`` (seen from ``T_world_cam``, every ``stride``-th pixel) and masked as
    ``settings`` say; ``views`` counts the frames that saw each voxel (None: no view mask); ``class_lut`` maps the
    map's class ids to the network's (0: a class the network does not have)."""
    view = map_view(m, frame, T_world_cam, min_depth=min_depth, max_depth=max_depth, stride=stride)
    cls = view.labels.astype(np.int64)
    has = cls != int(EMPTY_LABEL)
    if class_lut is not None:
        cls = np.where(has, np.asarray(class_lut, np.int64)[np.where(has, cls, 0)], IGNORE)
    has &= cls != IGNORE
    cls = np.where(has, cls, IGNORE)
    masks = {"no_class": ~has, "low_confidence": view.confidence < settings.min_confidence}
    if views is not None:
        masks["few_views"] = views.counts_at(view.points) < settings.min_views
    d = frame.depth[::stride, ::stride]
    edges = depth_edges(d, radius=settings.edge_px, jump_m=settings.edge_jump_m,
                        jump_share=settings.edge_jump_share)
    v, u = np.divmod(view.pixels, frame.depth.shape[1])
    masks["depth_edge"] = edges[v // stride, u // stride]
    keep = np.ones(len(cls), bool)
    removed = {}
    for reason in REASONS:
        if reason in masks:
            drop = keep & masks[reason]
            removed[reason] = int(drop.sum())
            keep &= ~drop
    return PseudoLabels(labels=view.image(np.where(keep, cls, IGNORE), IGNORE, np.uint16),
                        map_labels=view.image(cls, IGNORE, np.uint16),
                        confidence=view.image(view.confidence, 0.0, np.float32), stride=int(stride),
                        with_depth=len(cls), removed=removed)


def confident_network(p: PseudoLabels, network: np.ndarray, confidence: np.ndarray, threshold: float | None) -> None:
    """Drop, in place, the pseudo-labels of ``p`` where the network's class (``network``, on the same grid) differs
    and its probability ``confidence`` is at least ``threshold`` (None: keep them all)."""
    drop = np.zeros(p.labels.shape, bool)
    if threshold is not None:
        drop = (p.labels != IGNORE) & (np.asarray(confidence) >= threshold) & (np.asarray(network) != p.labels)
        p.labels[drop] = IGNORE
    p.removed["confident_network"] = int(drop.sum())


@dataclass
class PseudoLabelStats:
    """Coverage of the pseudo-labels over frames and, where the frames carry true labels, their accuracy beside
    the network's on the same pixels."""

    num_classes: int
    frames: int = 0
    with_depth: int = 0
    kept: int = 0
    removed: dict[str, int] = field(default_factory=lambda: dict.fromkeys(REASONS, 0))
    conf_pseudo: np.ndarray = field(init=False)  # (K, K) rows = truth, columns = pseudo-label, kept pixels
    conf_network: np.ndarray = field(init=False)  # (K, K) the network's label on the same pixels
    conf_map: np.ndarray = field(init=False)  # (K, K) the map's label before masking, wherever it has one
    truth: bool = False

    def __post_init__(self) -> None:
        k = self.num_classes
        self.conf_pseudo = np.zeros((k, k), np.int64)
        self.conf_network = np.zeros((k, k), np.int64)
        self.conf_map = np.zeros((k, k), np.int64)

    def add(self, p: PseudoLabels, truth: np.ndarray | None = None, network: np.ndarray | None = None) -> None:
        """One frame's pseudo-labels, with its true labels and the network's labels on the same grid (or None)."""
        self.frames += 1
        self.with_depth += p.with_depth
        self.kept += p.kept
        for reason, n in p.removed.items():
            self.removed[reason] = self.removed.get(reason, 0) + n
        if truth is None:
            return
        self.truth = True
        k = self.num_classes
        labelled = truth != IGNORE
        kept = labelled & (p.labels != IGNORE)
        self.conf_pseudo += confusion(p.labels[kept], truth[kept], k)
        if network is not None:
            self.conf_network += confusion(network[kept], truth[kept], k)
        mapped = labelled & (p.map_labels != IGNORE)
        self.conf_map += confusion(p.map_labels[mapped], truth[mapped], k)

    def summary(self) -> dict:
        """Coverage (kept / pixels with a depth), the share each mask removed and, with ground truth, pixel accuracy
        and MIoU of the pseudo-labels and of the network on the kept pixels, and of the unmasked map."""
        from semmap.eval.semantic import scores

        n = max(self.with_depth, 1)
        out: dict = {"frames": self.frames, "pixels_with_depth": self.with_depth, "pixels_kept": self.kept,
                     "coverage": round(self.kept / n, 4),
                     "removed": {r: round(v / n, 4) for r, v in self.removed.items()}}
        if self.truth:
            p, m = scores(self.conf_pseudo, ignore=IGNORE), scores(self.conf_map, ignore=IGNORE)
            out.update({"accuracy": round(p.accuracy, 4), "miou": round(p.miou, 4),
                        "map_accuracy": round(m.accuracy, 4), "map_miou": round(m.miou, 4)})
            if self.conf_network.any():
                net = scores(self.conf_network, ignore=IGNORE)
                out.update({"network_accuracy": round(net.accuracy, 4), "network_miou": round(net.miou, 4)})
        return out
