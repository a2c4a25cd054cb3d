"""``--segmenter structure``: per-pixel wall, floor and ceiling probabilities of one RGB-D frame from its depth
and the direction of gravity, sure where a large plane fits well and nothing lies behind it.

Alone it labels the room's shell and leaves every other pixel ``unknown``; ``NAME+structure``
(:mod:`semmap.perception.structure.compose`) lets a network name the rest. In a sequence with poses the up
direction and the floor and ceiling heights found so far are kept in the world frame and carried into each new
frame, so a floor seen in a corner of the image is still the floor."""

from __future__ import annotations

import logging
from dataclasses import dataclass, field, replace

import numpy as np

from semmap.geometry import pixel_rays
from semmap.labels import INDOOR_LABELS
from semmap.perception.structure._kernels import pixel_probabilities
from semmap.perception.structure.gravity import (
    UPRIGHT,
    UpEstimate,
    UpSource,
    estimate_up,
    unit,
    up_in_camera,
    up_in_world,
)
from semmap.perception.structure.planes import CEILING, FLOOR, WALL, Plane, horizontal_plane, wall_planes
from semmap.perception.structure.surface import Surface, surface_of
from semmap.types import EMPTY_LABEL, Frame, LabelSet, TopKProbs

log = logging.getLogger("semmap")

#: The classes structure names, in the order of its probability planes.
STRUCTURE_CLASSES = (WALL, FLOOR, CEILING)
#: The most a pixel's structure probabilities add up to: depth alone never rules out a poster on the wall.
MAX_SURE = 0.95
#: A pixel's normal agrees fully with its plane within this angle, not at all beyond the second (degrees).
NORMAL_FULL_DEG, NORMAL_NONE_DEG = 30.0, 60.0
#: A pixel is on a plane within the depth noise's tolerance (never more than this, metres), with a fall-off cut
#: this many half-tolerances further out. (A 4 cm cap and a 1.5 cut kept the redkitchen map's floor labels on the
#: plane, 89.7 %, but left 31 % of the floor unlabelled; the labels it removed lay on the floor, which 7-Scenes'
#: map bends up to 10 cm from one plane in its far corner.)
MAX_PIXEL_TOLERANCE_M, MAX_EXCESS = 0.1, 2.0
#: Agreement given to a pixel whose cell has no normal (a depth edge, a hole next to it).
NO_NORMAL_AGREEMENT = 0.8
#: A posed frame's wall at least this sure is remembered for later frames of the sequence.
REMEMBER_WALL_SURE = 0.7
#: Two walls closer than this in direction (degrees) and offset (metres) are one.
SAME_WALL_DEG, SAME_WALL_M = 6.0, 0.1
#: An up direction from depth is kept for the sequence's world estimate only with this much surface support.
MIN_UP_SUPPORT = 0.5


@dataclass(frozen=True)
class StructureView:
    """What structure found in one frame: the planes (camera frame), the up direction and where it came from,
    and the per-pixel probabilities (H, W, 3) of wall, floor and ceiling."""

    planes: tuple[Plane, ...]
    up: UpEstimate
    probs: np.ndarray

    def plane(self, kind: str) -> Plane | None:
        return next((p for p in self.planes if p.kind == kind), None)


@dataclass
class _WorldMemory:
    """What a posed sequence has learnt so far, in the world frame: the up direction (sum of the frames'
    estimates weighted by their support) and the floor and ceiling heights along it (area-weighted)."""

    up_sum: np.ndarray = field(default_factory=lambda: np.zeros(3))
    levels: dict[str, list[tuple[float, float]]] = field(default_factory=lambda: {FLOOR: [], CEILING: []})
    walls: list[tuple[np.ndarray, float, float]] = field(default_factory=list)  #: (normal, offset, sure), world

    def wall_sure(self, normal: np.ndarray, offset: float) -> float:
        """How sure earlier frames were of a wall on this world plane (0 for none)."""
        best = 0.0
        for n, o, sure in self.walls:
            if n @ normal > np.cos(np.radians(SAME_WALL_DEG)) and abs(o - offset) < SAME_WALL_M:
                best = max(best, sure)
        return best

    def add_wall(self, normal: np.ndarray, offset: float, sure: float) -> None:
        """Remember a wall a frame was sure of (the surest of the planes that coincide)."""
        for i, (n, o, s) in enumerate(self.walls):
            if n @ normal > np.cos(np.radians(SAME_WALL_DEG)) and abs(o - offset) < SAME_WALL_M:
                if sure > s:
                    self.walls[i] = (normal, offset, sure)
                return
        self.walls.append((normal, offset, sure))

    @property
    def up(self) -> np.ndarray | None:
        n = float(np.linalg.norm(self.up_sum))
        return self.up_sum / n if n > 1e-9 else None

    def level(self, kind: str) -> float | None:
        """Area-weighted median height of the floor (or ceiling) found so far."""
        found = self.levels[kind]
        if not found:
            return None
        h = np.array([x for x, _ in found])
        w = np.array([a for _, a in found])
        order = np.argsort(h)
        cum = np.cumsum(w[order])
        return float(h[order][np.searchsorted(cum, cum[-1] / 2)])


class StructureSegmenter:
    """Wall, floor and ceiling of each frame (the segmenter protocol) in ``label_set`` (semmap's indoor classes
    unless another set names them too). ``up_world``: a gravity-aligned world frame's up axis (``--up``), used
    for frames with a pose; frames that carry their own up direction (an accelerometer) use that first."""

    name = "structure"
    uses_pose = True  #: wants each frame with the pose the run gives it (the schedule passes it)

    def __init__(self, *, k: int = 3, up_world: np.ndarray | None = None, label_set: LabelSet = INDOOR_LABELS,
                 min_depth: float = 0.1, max_depth: float = 10.0):
        self.k = int(k)
        self._label_set = label_set
        self.ids = np.array([label_set.id_of(c) for c in STRUCTURE_CLASSES], np.uint16)
        self.up_world = None if up_world is None else unit(up_world)
        self.min_depth, self.max_depth = min_depth, max_depth
        self.memory = _WorldMemory()
        self.sources: dict[str, int] = {}  #: frames per up source (for the report)

    @property
    def label_set(self) -> LabelSet:
        return self._label_set

    @property
    def output_classes(self) -> np.ndarray:
        """The ids of ``label_set`` this segmenter can name (wall, floor, ceiling): what it is scored on."""
        return self.ids

    def _up(self, frame: Frame, surface: Surface) -> UpEstimate:
        """The frame's up direction in the camera frame, first found wins (see :class:`UpSource`)."""
        T = frame.T_world_cam
        if frame.up_cam is not None:
            return UpEstimate(unit(frame.up_cam), UpSource.DATASET, 1.0)
        if self.up_world is not None and T is not None:
            return UpEstimate(up_in_camera(self.up_world, T), UpSource.DECLARED, 1.0)
        known = self.memory.up if T is not None else None
        prior = UPRIGHT if known is None else up_in_camera(known, T)
        est = estimate_up(surface, prior)
        if T is not None and est.support >= MIN_UP_SUPPORT:
            self.memory.up_sum += est.support * up_in_world(est.up, T)
        if known is not None:
            return UpEstimate(est.up, UpSource.MAP, est.support)
        return est

    def analyse(self, frame: Frame) -> StructureView:
        """The planes, up direction and per-pixel probabilities of one frame (updating the sequence's memory)."""
        surface = surface_of(frame.depth, frame.intrinsics, min_depth=self.min_depth, max_depth=self.max_depth)
        up = self._up(frame, surface)
        self.sources[up.source.value] = self.sources.get(up.source.value, 0) + 1
        T = frame.T_world_cam
        world_up = self.memory.up if up.source in (UpSource.MAP, UpSource.DEPTH) else self.up_world
        if up.source == UpSource.DATASET and T is not None:
            world_up = up_in_world(up.up, T)
        lift = None if T is None or world_up is None else float(world_up @ np.asarray(T, np.float64)[:3, 3])
        planes: list[Plane] = []
        for kind in (FLOOR, CEILING):
            known = self.memory.level(kind) if lift is not None else None
            plane = horizontal_plane(surface, up.up, kind, near=None if known is None else known - lift)
            if plane is not None:
                planes.append(plane)
                if lift is not None:
                    level = -plane.offset if kind == FLOOR else plane.offset
                    self.memory.levels[kind].append((level + lift, plane.area))
        floor = next((p for p in planes if p.kind == FLOOR), None)
        walls = wall_planes(surface, up.up, floor_height=None if floor is None else -floor.offset)
        planes += walls if T is None else [self._remembered(w, T) for w in walls]
        probs = self._pixel_probabilities(frame, surface, planes)
        return StructureView(tuple(planes), up, probs)

    def _remembered(self, wall: Plane, T: np.ndarray) -> Plane:
        """A frame's wall made as sure as earlier frames were of the same world plane, and remembered when sure:
        a wall seen whole once is a wall when a later view shows only its lower part."""
        R, t = np.asarray(T, np.float64)[:3, :3], np.asarray(T, np.float64)[:3, 3]
        normal = R @ wall.normal
        offset = float(wall.offset - normal @ t)
        if wall.sure >= REMEMBER_WALL_SURE:
            self.memory.add_wall(normal, offset, wall.sure)
        known = self.memory.wall_sure(normal, offset)
        return wall if known <= wall.sure else replace(wall, sure=known)

    def _pixel_probabilities(self, frame: Frame, surface: Surface, planes: list[Plane]) -> np.ndarray:
        """(H, W, 3) float32: for each class the best of its planes at each pixel, by the pixel's distance to the
        plane (against the depth noise) and its normal's agreement, times the plane's sureness."""
        h, w = frame.depth.shape
        out = np.zeros((h, w, 3), np.float32)
        if not planes:
            return out
        rays = pixel_rays(frame.intrinsics)
        table = np.array([[*p.normal, p.offset, p.sure] for p in planes], np.float64)
        kinds = np.array([STRUCTURE_CLASSES.index(p.kind) for p in planes], np.int64)
        pixel_probabilities(np.ascontiguousarray(frame.depth, np.float32), rays.x, rays.y,
                            np.ascontiguousarray(surface.normals, np.float64), surface.cell, table, kinds,
                            float(self.min_depth), float(self.max_depth), float(np.cos(np.radians(NORMAL_NONE_DEG))),
                            float(np.cos(np.radians(NORMAL_FULL_DEG))), NO_NORMAL_AGREEMENT, MAX_SURE,
                            MAX_PIXEL_TOLERANCE_M, MAX_EXCESS, out)
        return out

    def probabilities(self, frame: Frame) -> np.ndarray:
        """(H, W, 3) float32 probabilities of wall, floor and ceiling (their sum is at most 0.95)."""
        return self.analyse(frame).probs

    def segment(self, frame: Frame) -> TopKProbs:
        """Top-k of wall, floor, ceiling and ``unknown`` (what is not the room's shell) per pixel."""
        return structure_topk(self.probabilities(frame), self.ids, self.k)


def structure_topk(probs: np.ndarray, ids: np.ndarray, k: int) -> TopKProbs:
    """Top-k sets of (H, W, 3) structure probabilities with the rest of the mass on ``unknown`` (id 0)."""
    h, w, _ = probs.shape
    full = np.concatenate([probs, 1.0 - probs.sum(axis=-1, keepdims=True)], axis=-1).reshape(-1, 4)
    labels = np.concatenate([ids, [0]]).astype(np.uint16)
    order = np.argsort(-full, axis=1, kind="stable")[:, :k]
    top = np.take_along_axis(full, order, axis=1).astype(np.float32)
    out_labels = labels[order]
    if k > 4:
        pad = k - 4
        out_labels = np.concatenate([out_labels, np.full((len(full), pad), EMPTY_LABEL, np.uint16)], axis=1)
        top = np.concatenate([top, np.zeros((len(full), pad), np.float32)], axis=1)
    return TopKProbs(out_labels.reshape(h, w, -1), top.reshape(h, w, -1))
