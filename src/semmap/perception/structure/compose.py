"""``--segmenter NAME+structure``: a network's classes with the room's shell from geometry.

The rule, per pixel, with ``s`` the structure segmenter's total wall + floor + ceiling probability (its
sureness, at most 0.95) and ``a`` the share of it that stands (1 minus the network's probability of a class that
lies flat on a wall or floor: door, window, picture, whiteboard, curtain, so a poster stays a poster)::

    P(c) = a * P_structure(c) + (1 - a * s) * P_network(c)

Structure owns wall, floor and ceiling where it is sure; where it is not (``s`` near 0: furniture, clutter, no
depth) the network's distribution stands as it is, its own wall / floor / ceiling included. The network's
classes are first folded into the output label set (semmap's indoor classes) by name, or through the shipped
class mapping of its label set (``class_maps/pascal-voc.json`` for ESPNetv2, ``nyu40.json``); a class with no
counterpart becomes ``unknown``."""

from __future__ import annotations

import logging

import numba as nb
import numpy as np

from semmap.errors import ConfigError
from semmap.labels import INDOOR_LABELS
from semmap.perception.base import Preparable, Segmenter
from semmap.perception.class_map import read_class_map, shipped_class_maps
from semmap.perception.structure.segmenter import STRUCTURE_CLASSES, StructureSegmenter
from semmap.types import EMPTY_LABEL, Frame, LabelSet, TopKProbs

log = logging.getLogger("semmap")

#: Classes a network may see lying flat on a wall or the floor, where depth sees only the plane.
ON_PLANE = ("door", "window", "picture", "whiteboard", "curtain")
#: Suffix of ``--segmenter NAME+structure``.
SUFFIX = "+structure"
#: Shipped class mappings by the first names of the label set they fold (the network's own label sets).
_FOLDS_BY_FIRST_NAMES = {("background", "aeroplane", "bicycle"): "pascal-voc", ("unknown", "wall", "floor", "cabinet"):
                         "nyu40", ("wall", "floor", "cabinet", "bed"): "nyu40"}


def fold_to(label_set: LabelSet, target: LabelSet = INDOOR_LABELS) -> tuple[np.ndarray, list[str]]:
    """(K,) uint16: the output id of each of ``label_set``'s classes, and the names that found none. A label set
    semmap has a shipped mapping for goes through it; any other by equal names (case and spaces ignored)."""
    names = tuple(label_set.names)
    ids = np.zeros(len(names), np.uint16)
    shipped = next((shipped_class_maps()[f] for first, f in _FOLDS_BY_FIRST_NAMES.items()
                    if names[: len(first)] == first), None)
    if shipped is not None and target is INDOOR_LABELS:
        fold = read_class_map(shipped, names)
        ids[:] = np.argmax(fold.matrix, axis=1)
    else:
        own = {" ".join(n.split()).lower(): i for i, n in enumerate(target.names)}
        for i, n in enumerate(names):
            ids[i] = own.get(" ".join(str(n).split()).lower(), 0)
    dropped = [n for i, n in enumerate(names) if ids[i] == 0 and i > 0]
    return ids, dropped


class WithStructure:
    """A segmenter's classes (folded into ``label_set``) combined with :class:`StructureSegmenter`'s wall, floor
    and ceiling by the rule of this module."""

    uses_pose = True

    def __init__(self, network: Segmenter, structure: StructureSegmenter, *, k: int = 3,
                 label_set: LabelSet = INDOOR_LABELS):
        self.network, self.structure, self.k = network, structure, int(k)
        self.name = f"{network.name}{SUFFIX}"
        self._label_set = label_set
        self.fold, dropped = fold_to(network.label_set, label_set)
        if dropped:
            log.debug("%s: %d of its classes have no counterpart among the map's and count as unknown (%s%s)",
                     network.name, len(dropped), ", ".join(dropped[:6]), ", ..." if len(dropped) > 6 else "")
        if len(label_set) > EMPTY_LABEL:
            raise ConfigError(f"{self.name}: {len(label_set)} classes do not fit a top-k set")
        self.on_plane = np.zeros(len(label_set), np.bool_)
        for name in ON_PLANE:
            if name in label_set.names:
                self.on_plane[label_set.id_of(name)] = True
        self.structure_ids = structure.ids

    @property
    def label_set(self) -> LabelSet:
        return self._label_set

    @property
    def output_classes(self) -> np.ndarray:
        """The ids of ``label_set`` the network (folded) or structure can name."""
        inner = getattr(self.network, "output_classes", None)
        network = self.fold if inner is None else self.fold[np.asarray(inner)]
        return np.union1d(network[network > 0], self.structure_ids).astype(np.uint16)

    def prepare(self, frame: Frame) -> float:
        """The network's start-up cost (an ONNX export, a session), paid before the frame loop."""
        return self.network.prepare(frame) if isinstance(self.network, Preparable) else 0.0

    def segment(self, frame: Frame) -> TopKProbs:
        return self._combine(frame, self.network.segment(frame))

    def segment_batch(self, frames: list[Frame]) -> list[TopKProbs]:
        """The network's batch, then structure frame by frame (in order: it remembers the sequence)."""
        batch = getattr(self.network, "segment_batch", None)
        sems = list(batch(frames)) if batch is not None else [self.network.segment(f) for f in frames]
        return [self._combine(f, s) for f, s in zip(frames, sems, strict=True)]

    def _combine(self, frame: Frame, net: TopKProbs) -> TopKProbs:
        probs = self.structure.probabilities(frame)
        h, w = probs.shape[:2]
        flat = net.reshape_flat()
        labels = np.where(flat.labels == EMPTY_LABEL, EMPTY_LABEL,
                          self.fold[np.minimum(flat.labels, len(self.fold) - 1)]).astype(np.uint16)
        out_labels = np.empty((h * w, self.k), np.uint16)
        out_probs = np.empty((h * w, self.k), np.float32)
        combine_sets(np.ascontiguousarray(labels), np.ascontiguousarray(flat.probs, np.float32),
                     np.ascontiguousarray(probs.reshape(-1, 3)), self.structure_ids, self.on_plane,
                     out_labels, out_probs)
        return TopKProbs(out_labels.reshape(h, w, self.k), out_probs.reshape(h, w, self.k))


@nb.njit(parallel=True, cache=True, nogil=True)
def combine_sets(net_labels: np.ndarray, net_probs: np.ndarray, structure: np.ndarray, structure_ids: np.ndarray,
                 on_plane: np.ndarray, out_labels: np.ndarray, out_probs: np.ndarray) -> None:
    """Per row: the network's top-k set (labels already in the output set; repeated labels add up) and the
    structure probabilities of ``structure_ids`` combined by the module's rule; the top ``out`` width kept,
    sorted, the rest left to the "others" mass."""
    n, kn = net_labels.shape
    ko = out_labels.shape[1]
    for r in nb.prange(n):
        cand_l = np.full(kn + 3, EMPTY_LABEL, np.uint16)
        cand_p = np.zeros(kn + 3, np.float32)
        m = 0
        flat = 0.0
        for j in range(kn):
            lab = net_labels[r, j]
            if lab != EMPTY_LABEL and on_plane[lab]:
                flat += net_probs[r, j]
        s = structure[r, 0] + structure[r, 1] + structure[r, 2]
        a = 1.0 - min(flat, 1.0)
        keep = 1.0 - a * s
        for j in range(kn):
            lab = net_labels[r, j]
            p = net_probs[r, j]
            if lab == EMPTY_LABEL or p <= 0.0:
                continue
            found = -1
            for q in range(m):
                if cand_l[q] == lab:
                    found = q
            if found < 0:
                cand_l[m] = lab
                cand_p[m] = keep * p
                m += 1
            else:
                cand_p[found] += keep * p
        for i in range(3):
            p = a * structure[r, i]
            if p <= 0.0:
                continue
            lab = structure_ids[i]
            found = -1
            for q in range(m):
                if cand_l[q] == lab:
                    found = q
            if found < 0:
                cand_l[m] = lab
                cand_p[m] = p
                m += 1
            else:
                cand_p[found] += p
        for j in range(ko):  # selection of the largest, ties to the lower id
            best = -1
            for q in range(m):
                if cand_l[q] != EMPTY_LABEL and (best < 0 or cand_p[q] > cand_p[best]
                                                 or (cand_p[q] == cand_p[best] and cand_l[q] < cand_l[best])):
                    best = q
            if best < 0:
                out_labels[r, j] = EMPTY_LABEL
                out_probs[r, j] = 0.0
            else:
                out_labels[r, j] = cand_l[best]
                out_probs[r, j] = cand_p[best]
                cand_l[best] = EMPTY_LABEL


__all__ = ["ON_PLANE", "STRUCTURE_CLASSES", "SUFFIX", "WithStructure", "combine_sets", "fold_to"]
