"""Instances from any semantic segmenter: connected regions of one object class, cut at depth discontinuities.

A semantic segmentation says "chair" but not which chair. Two chairs side by side are one region of the class
image, yet the depth image jumps between them (the nearer one occludes the farther) or the floor shows between
them. So pixels are cut wherever the class changes or the depth jumps by more than ``DEPTH_JUMP_REL`` of the
depth (at least ``DEPTH_JUMP_MIN``), and the rest is split into 4-connected components in one OpenCV pass over
the whole image; a component is an instance of its class when it is large enough and its class is an object
class. The cut pixels (a one-pixel seam along every outline) belong to no instance, which also keeps the mixed
depth of object edges out of the object clouds.

A nearer thing in front of an object cuts it in two: a table seen on both sides of a chair's back, or between its
slats. Two parts are joined (``join``) when enough rows or columns (``JOIN_MIN_LINES``) cross from one to the
other through pixels the camera sees nearer (the occluder) and none farther (a real space between two things
would show the background), and the depth on both sides continues one surface (within the jump threshold plus a
slope of 45 degrees over the hidden span). Two chairs side by side stay two: between them the camera sees the
floor or the wall, or one chair directly in front of the other.
"""

from __future__ import annotations

import cv2
import numpy as np

from semmap.errors import ConfigError
from semmap.perception.base import Segmenter
from semmap.perception.instances._component_kernels import occluded_links
from semmap.perception.instances.base import thing_classes
from semmap.types import Frame, Instances, LabelSet, TopKProbs

#: Depth jump (fraction of the depth) between neighbouring pixels that separates two instances.
DEPTH_JUMP_REL = 0.04
#: ... but never less than this (metres): Kinect depth noise between neighbours stays below it up to ~3 m.
DEPTH_JUMP_MIN = 0.03
#: Components smaller than this share of the image are dropped (300 px at 640x480).
MIN_AREA_FRACTION = 300 / (640 * 480)
#: Parts of one class are joined across an occluder at most this share of the image's width (or height) wide ...
JOIN_MAX_GAP = 0.3
#: ... when at least this many rows and columns cross from one to the other through it ...
JOIN_MIN_LINES = 3
#: ... and the depth on both sides differs by at most the jump threshold plus this times the hidden span (45 deg)
JOIN_SLOPE = 1.0
#: ... unless more than this share as many rows and columns see the background between them (two chairs behind
#: a table: the table hides the space between their seats, the wall shows between their backs)
JOIN_APART_SHARE = 0.25


class ComponentInstances:
    """:class:`~semmap.perception.instances.InstanceSource` over class probabilities of ``label_set``: the run's
    (any :class:`~semmap.perception.base.Segmenter`, or label images), or ``segmenter``'s when none are given."""

    name = "components"
    needs_semantics = True

    def __init__(self, label_set: LabelSet, segmenter: Segmenter | None = None, *,
                 min_area_fraction: float = MIN_AREA_FRACTION, depth_jump_rel: float = DEPTH_JUMP_REL,
                 depth_jump_min: float = DEPTH_JUMP_MIN, join: bool = True) -> None:
        if not 0.0 <= min_area_fraction < 1.0 or depth_jump_rel <= 0 or depth_jump_min < 0:
            raise ConfigError("components: min_area_fraction in [0, 1), depth_jump_rel > 0, depth_jump_min >= 0")
        self.segmenter = segmenter
        self._label_set = label_set
        self.min_area_fraction = float(min_area_fraction)
        self.depth_jump_rel, self.depth_jump_min = float(depth_jump_rel), float(depth_jump_min)
        self._things = thing_classes(label_set)
        self.join = bool(join)

    @property
    def label_set(self) -> LabelSet:
        return self._label_set

    def detect(self, frame: Frame, semantics: TopKProbs | None = None) -> Instances:
        """Instances of ``frame`` from ``semantics`` (the segmenter runs when they are not given)."""
        if semantics is None:
            if self.segmenter is None:
                raise ConfigError("components: no class probabilities for this frame and no segmenter to make them")
            semantics = self.segmenter.segment(frame)
        return components(semantics.labels[..., 0], semantics.probs[..., 0], frame.depth, self._things,
                          min_pixels=max(1, round(self.min_area_fraction * frame.depth.size)),
                          depth_jump_rel=self.depth_jump_rel, depth_jump_min=self.depth_jump_min,
                          join_focal_px=frame.intrinsics.fx if self.join else None)


def components(labels: np.ndarray, confidence: np.ndarray, depth: np.ndarray, things: np.ndarray, *,
               min_pixels: int, depth_jump_rel: float = DEPTH_JUMP_REL,
               depth_jump_min: float = DEPTH_JUMP_MIN, join_focal_px: float | None = None) -> Instances:
    """Instances of a class image (H, W) with its per-pixel confidence and depth (metres, 0 = invalid): connected
    regions of one object class (``things`` (K,) bool) without a class change or a depth jump inside, of at least
    ``min_pixels`` pixels; score = mean confidence. With ``join_focal_px`` (the camera's focal length, pixels),
    parts of one class an occluder cut apart are one instance (see the module docstring)."""
    labels = np.asarray(labels).astype(np.int64)
    if labels.shape != depth.shape:
        raise ConfigError(f"class image {labels.shape} and depth {depth.shape} differ in size")
    is_thing = np.zeros(max(int(labels.max(initial=0)) + 1, len(things)), bool)
    is_thing[: len(things)] = things
    cut = _seams(labels, np.asarray(depth, np.float32), depth_jump_rel, depth_jump_min)
    region = is_thing[labels] & ~cut
    n, comp = cv2.connectedComponents(region.astype(np.uint8), connectivity=4, ltype=cv2.CV_32S)
    if n <= 1:
        return Instances.empty(*labels.shape)
    flat = comp.ravel()
    inside = flat > 0
    # class of each component: every pixel of a component has the same class (class changes are cut)
    cls = np.zeros(n, np.int64)
    cls[flat[inside]] = labels.ravel()[inside]
    if join_focal_px is not None:
        n, comp = _join_occluded(comp, cls, np.asarray(depth, np.float32), depth_jump_rel, depth_jump_min,
                                 float(join_focal_px))
        flat = comp.ravel()
        cls_joined = np.zeros(n, np.int64)
        cls_joined[flat[inside]] = labels.ravel()[inside]
        cls = cls_joined
    area = np.bincount(flat, minlength=n)[1:]
    conf = np.bincount(flat, weights=np.asarray(confidence, np.float64).ravel(), minlength=n)[1:] / np.maximum(area, 1)
    big = area >= min_pixels
    renumber = np.zeros(n, np.int32)
    renumber[1:][big] = np.arange(1, int(big.sum()) + 1)
    return Instances.from_id_image(renumber[comp], cls[1:][big], conf[big].astype(np.float32))


def _join_occluded(comp: np.ndarray, cls: np.ndarray, depth: np.ndarray, rel: float, floor: float,
                   focal_px: float) -> tuple[int, np.ndarray]:
    """Components renumbered 1..n-1 after joining those an occluder cut apart (:func:`occluded_links` on at least
    ``JOIN_MIN_LINES`` rows and columns); returns (n, id image)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    max_gap = max(2, round(JOIN_MAX_GAP * max(comp.shape)))
    links, apart = occluded_links(comp, cls, depth, max_gap, rel, floor, JOIN_SLOPE, focal_px)
    n = len(cls)
    if len(links) == 0:
        return n, comp
    pairs, counts = np.unique(links[:, 0] * n + links[:, 1], return_counts=True)
    seen_apart = np.bincount(np.searchsorted(pairs, apart[:, 0] * n + apart[:, 1]).clip(0, len(pairs) - 1),
                             weights=np.isin(apart[:, 0] * n + apart[:, 1], pairs), minlength=len(pairs))
    pairs = pairs[(counts >= JOIN_MIN_LINES) & (seen_apart <= JOIN_APART_SHARE * counts)]
    if len(pairs) == 0:
        return n, comp
    graph = coo_matrix((np.ones(len(pairs)), (pairs // n, pairs % n)), shape=(n, n))
    _, group = connected_components(graph, directed=False)
    # background keeps 0, every joined group one id from 1 on
    first = np.zeros(group.max() + 1, np.int64)
    order = np.unique(group[1:])
    first[order] = np.arange(1, len(order) + 1)
    renumber = first[group].astype(np.int32)
    renumber[0] = 0
    return len(order) + 1, renumber[comp]


def _seams(labels: np.ndarray, depth: np.ndarray, rel: float, floor: float) -> np.ndarray:
    """(H, W) bool: pixels whose right or lower neighbour has another class or lies across a depth jump."""
    cut = np.zeros(labels.shape, bool)
    for axis in (0, 1):
        a = [slice(None), slice(None)]
        b = [slice(None), slice(None)]
        a[axis], b[axis] = slice(None, -1), slice(1, None)
        la, lb = labels[tuple(a)], labels[tuple(b)]
        da, db = depth[tuple(a)], depth[tuple(b)]
        both = (da > 0) & (db > 0)
        jump = both & (np.abs(da - db) > np.maximum(floor, rel * np.minimum(da, db)))
        cut[tuple(a)] |= (la != lb) | jump
    return cut
