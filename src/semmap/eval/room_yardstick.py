"""A real yardstick without hand labels: wall, floor and ceiling of a recorded room from the planes of its
ground-truth-posed map, rendered back into each frame (issue 45's 7-Scenes redkitchen yardstick).

The whole sequence sees far more of each plane than one frame does, so the room's planes are found once, over
every frame's points in the world frame: the up direction that makes most of the surface horizontal or vertical,
the floor (lowest large upward-facing plane), the ceiling (highest downward-facing one, if seen), the walls (large
vertical planes with nothing behind them in the whole map) and a table top (the largest upward-facing plane 0.55-
0.85 m above the floor). A pixel is labelled wall / floor / ceiling when its point lies on one of them (within the
depth noise plus what the poses' own error spreads a plane over) and its surface faces like it; every other pixel
with depth is ``other``, so a segmenter that calls a cabinet front a wall is counted wrong."""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np

from semmap.labels import INDOOR_LABELS
from semmap.perception.base import Segmenter
from semmap.perception.structure.compose import fold_to
from semmap.perception.structure.gravity import _refine, unit
from semmap.perception.structure.planes import FLOOR, WALL, horizontal_plane, wall_planes
from semmap.perception.structure.surface import Surface, plane_tolerance, surface_of
from semmap.types import Frame

#: Classes of the yardstick's label images.
NO_DEPTH, WALL_ID, FLOOR_ID, CEILING_ID, OTHER_ID = 0, 1, 2, 3, 4
YARDSTICK_NAMES = ("no depth", "wall", "floor", "ceiling", "other")
#: How far (metres) the ground-truth poses spread one plane over the frames, added to the depth noise.
POSE_SPREAD_M = 0.03
#: A pixel's surface faces like its plane within this angle.
FACING_DEG = 35.0
#: Table-top heights above the floor (metres).
TABLE_HEIGHTS = (0.55, 0.85)
#: Two walls closer than this in direction (degrees) and offset (metres) are one.
SAME_WALL_DEG, SAME_WALL_M = 5.0, 0.15


@dataclass(frozen=True)
class WorldPlane:
    """A plane in the world frame: points x with ``normal . x + offset = 0``, ``normal`` facing into the room."""

    normal: np.ndarray
    offset: float

    def distance(self, points: np.ndarray) -> np.ndarray:
        return points @ self.normal + self.offset


@dataclass(frozen=True)
class RoomPlanes:
    """The room's shell in the world frame, and a table top; ``frames`` the number of frames it was fitted on."""

    up: np.ndarray
    floor: WorldPlane | None
    ceiling: WorldPlane | None
    walls: tuple[WorldPlane, ...]
    table: WorldPlane | None
    frames: int = 0
    notes: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        def plane(p: WorldPlane | None) -> dict | None:
            return None if p is None else {"normal": [round(float(v), 5) for v in p.normal],
                                           "offset": round(float(p.offset), 4)}

        return {"up": [round(float(v), 5) for v in self.up], "floor": plane(self.floor),
                "ceiling": plane(self.ceiling), "walls": [plane(w) for w in self.walls], "table": plane(self.table),
                "frames": self.frames}


def _world_cells(frames: Iterable[Frame]) -> tuple[np.ndarray, ...]:
    """Every frame's working-grid cells with a normal, in the world frame: points, normals, areas, their depths
    from their cameras, the cameras' up directions (-y of each pose) and the number of frames."""
    pts, nrm, area, depth, cam_up, centres = [], [], [], [], [], []
    for f in frames:
        T = f.T_world_cam
        if T is None:
            continue
        s = surface_of(f.depth, f.intrinsics)
        ok = s.has_normal & s.valid
        R = T[:3, :3]
        pts.append(s.points[ok] @ R.T + T[:3, 3])
        nrm.append(s.normals[ok] @ R.T)
        area.append(s.area[ok])
        depth.append(s.points[ok][:, 2])
        cam_up.append(-R[:, 1])
        centres.append(T[:3, 3])
    if not pts:
        raise ValueError("no frame has a pose: the yardstick needs the ground-truth poses")
    return (np.vstack(pts), np.vstack(nrm), np.concatenate(area), np.concatenate(depth), np.array(cam_up),
            np.array(centres), len(pts))


def fit_room(frames: Iterable[Frame]) -> RoomPlanes:
    """The room's planes from posed frames (every few frames of a sequence is plenty)."""
    P, N, A, Z, cam_up, centres, n = _world_cells(frames)
    up = _refine(N, A, unit(cam_up.mean(axis=0)))
    # the planes are searched relative to the cameras' mean position (inside the room, where the walls face), as
    # one frame's are relative to its camera
    origin = centres.mean(axis=0)
    grid = Surface((P - origin)[:, None, :], N[:, None, :], A[:, None], 1, depth=Z[:, None])
    floor = horizontal_plane(grid, up, FLOOR)
    floor_w = None if floor is None else WorldPlane(up, floor.offset - float(up @ origin))
    ceiling = horizontal_plane(grid, up, "ceiling")
    ceiling_w = None if ceiling is None else WorldPlane(-up, ceiling.offset + float(up @ origin))
    walls: list[WorldPlane] = []
    for w in wall_planes(grid, up, floor_height=None if floor is None else -floor.offset):
        plane = WorldPlane(w.normal, w.offset - float(w.normal @ origin))
        if not any(np.degrees(np.arccos(np.clip(plane.normal @ o.normal, -1, 1))) < SAME_WALL_DEG
                   and abs(plane.offset - o.offset) < SAME_WALL_M for o in walls):
            walls.append(plane)
    table = None
    if floor_w is not None:
        height = P @ up + floor_w.offset  # above the floor
        top = (N @ up > np.cos(np.radians(15))) & (height > TABLE_HEIGHTS[0]) & (height < TABLE_HEIGHTS[1])
        if top.any():
            hist, edges = np.histogram(height[top], np.arange(*TABLE_HEIGHTS, 0.02), weights=A[top])
            level = (edges[int(np.argmax(hist))] + edges[int(np.argmax(hist)) + 1]) / 2
            table = WorldPlane(up, floor_w.offset - level)
    return RoomPlanes(up, floor_w, ceiling_w, tuple(walls), table, n)


def label_frame(frame: Frame, room: RoomPlanes) -> np.ndarray:
    """(H, W) uint8 yardstick labels of one posed frame: wall / floor / ceiling where the pixel's point lies on
    the room's plane and faces like it, ``other`` elsewhere with depth, ``no depth`` without."""
    T = frame.T_world_cam
    h, w = frame.depth.shape
    out = np.full((h, w), NO_DEPTH, np.uint8)
    if T is None:
        return out
    k = frame.intrinsics
    z = frame.depth.astype(np.float64)
    ok = np.isfinite(z) & (z > 0.1)
    x = z * ((np.arange(w) - k.cx) / k.fx)[None, :]
    y = z * ((np.arange(h) - k.cy) / k.fy)[:, None]
    world = np.stack([x, y, z], -1) @ T[:3, :3].T + T[:3, 3]
    s = surface_of(frame.depth, frame.intrinsics)
    rows = np.minimum(np.arange(h) // s.cell, s.normals.shape[0] - 1)
    cols = np.minimum(np.arange(w) // s.cell, s.normals.shape[1] - 1)
    normals = s.normals[rows][:, cols] @ T[:3, :3].T
    has_normal = np.any(normals != 0, axis=-1)
    tol = plane_tolerance(z) + POSE_SPREAD_M
    out[ok] = OTHER_ID
    cos = np.cos(np.radians(FACING_DEG))
    for planes, cls in (((room.floor,), FLOOR_ID), ((room.ceiling,), CEILING_ID), (room.walls, WALL_ID)):
        for p in planes:
            if p is None:
                continue
            on = ok & (np.abs(p.distance(world)) < tol) & (~has_normal | (normals @ p.normal > cos))
            out[on & (out == OTHER_ID)] = cls
    return out


def structure_confusion(predicted: np.ndarray, yardstick: np.ndarray) -> np.ndarray:
    """(3, 3) counts over the pixels with depth: rows wall / floor / ceiling, columns true positives, false
    positives (predicted there, the yardstick says otherwise) and false negatives. ``predicted`` holds the
    yardstick's ids (1 wall, 2 floor, 3 ceiling, anything else another class)."""
    scored = yardstick != NO_DEPTH
    out = np.zeros((3, 3), np.int64)
    for i, c in enumerate((WALL_ID, FLOOR_ID, CEILING_ID)):
        p, t = (predicted == c) & scored, yardstick == c
        out[i] = (np.sum(p & t), np.sum(p & ~t), np.sum(~p & t))
    return out


def iou_of(confusion: np.ndarray) -> dict[str, float | None]:
    """Wall, floor and ceiling IoU of a summed :func:`structure_confusion` (None for a class never seen)."""
    names = (WALL, FLOOR, "ceiling")
    out: dict[str, float | None] = {}
    for name, (tp, fp, fn) in zip(names, confusion, strict=True):
        out[name] = None if tp + fn == 0 else float(tp / (tp + fp + fn))
    return out


def as_yardstick_ids(label_set, top: np.ndarray) -> np.ndarray:
    """A segmenter's top classes (ids of its ``label_set``) as yardstick ids: wall / floor / ceiling by semmap's
    names (its classes folded into them), anything else ``other``."""
    indoor, _ = fold_to(label_set)
    names = np.asarray(INDOOR_LABELS.names)[indoor[np.minimum(top, len(indoor) - 1)]]
    out = np.full(top.shape, OTHER_ID, np.uint8)
    for name, i in ((WALL, WALL_ID), (FLOOR, FLOOR_ID), ("ceiling", CEILING_ID)):
        out[names == name] = i
    return out


def score_on_yardstick(segmenter: Segmenter, frames: Iterable[Frame], labels: Iterable[np.ndarray], *,
                       posed: bool = True) -> dict[str, float | None]:
    """Wall, floor and ceiling IoU of ``segmenter``'s top class against the yardstick's ``labels`` of ``frames``
    (in order; ``posed=False`` hides the poses: single frames)."""
    conf = np.zeros((3, 3), np.int64)
    for f, y in zip(frames, labels, strict=True):
        sem = segmenter.segment(f if posed else f.with_(T_world_cam=None))
        conf += structure_confusion(as_yardstick_ids(segmenter.label_set, sem.labels[..., 0]), y)
    return iou_of(conf)
