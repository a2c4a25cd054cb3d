"""Geometrically symmetric rooms whose two halves differ only in their classes: the test for semantic localization.

A furnished room is cut in two across its longer horizontal axis; the objects wholly inside the first half are
kept and each gets a twin turned 180° about the room's vertical centre line, so that the room's geometry maps
onto itself under that turn.  A twin keeps its mesh but takes a partner class (:data:`TWIN_CLASS`), so only the
semantics tell the two halves apart: a camera pose and its turned twin see the same depth image and different
labels.  Wall fixtures (doors, windows, pictures, ...), ceiling lights and the room shell keep their classes.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from semmap.sim.layout import Layout, Placed
from semmap.types import rot_z

#: Class of an object's turned twin: pairs of classes a segmentation network does not confuse
#: (see ``perception.oracle.CONFUSIONS``); wall fixtures and classes not listed keep their class.
_PAIRS: tuple[tuple[str, str], ...] = (
    ("desk", "bed"), ("table", "shelf"), ("chair", "cabinet"), ("sofa", "monitor"), ("cup", "book"),
    ("bottle", "keyboard"), ("plant", "box"), ("lamp", "nightstand"), ("pillow", "sink"), ("person", "counter"),
)
TWIN_CLASS: dict[str, str] = {**{a: b for a, b in _PAIRS}, **{b: a for a, b in _PAIRS}}
#: Objects must end this far short of the cutting plane to be kept (their twins then do not touch them).
CUT_GAP = 0.05
#: A ceiling fixture centred within this distance of the room's centre line maps onto itself and is kept once.
CENTRE_TOLERANCE = 0.01


def mirror_half(layout: Layout, room: int = 0) -> None:
    """Make ``room`` of ``layout`` symmetric under a 180° turn about its vertical centre line (in place):
    keep the objects wholly in its lower half along the longer axis, drop the rest (and keep-out boxes), and
    add a turned twin with the partner class of every kept object (children follow their parents)."""
    r = layout.rooms[room]
    axis = int(np.argmax(r.size[:2]))
    centre = 0.5 * (r.lo + r.hi)
    keep = [_kept(layout, i, room, axis, centre) for i in range(len(layout.placed))]
    for i, p in enumerate(layout.placed):  # children follow their parents (parents come first)
        if p.parent is not None and not keep[p.parent]:
            keep[i] = False
    new_index: dict[int | tuple[str, int], int] = {}  # original index, or ("twin", original) -> new index
    placed: list[Placed] = []
    for i, p in enumerate(layout.placed):
        if keep[i]:
            new_index[i] = len(placed)
            placed.append(replace(p, parent=None if p.parent is None else new_index[p.parent]))
    for i, p in enumerate(layout.placed):
        if not keep[i] or p.room != room or _on_centre(p, centre):
            continue
        parent = None if p.parent is None else new_index[("twin", p.parent)]
        new_index[("twin", i)] = len(placed)
        placed.append(_twin(p, centre, parent))
    layout.placed = placed
    layout.wall_of = {}


def _kept(layout: Layout, i: int, room: int, axis: int, centre: np.ndarray) -> bool:
    p = layout.placed[i]
    if p.mesh is None:
        return False  # keep-out boxes only guided the furnishing
    if p.room != room:
        return True
    if p.parent is not None:
        return True  # decided by the parent
    return bool(p.hi[axis] <= centre[axis] - CUT_GAP) or (p.mount == "ceiling" and _on_centre(p, centre))


def _on_centre(p: Placed, centre: np.ndarray) -> bool:
    mid = 0.5 * (p.lo + p.hi)
    return p.mount == "ceiling" and bool(np.linalg.norm(mid[:2] - centre[:2]) < CENTRE_TOLERANCE)


def _twin(p: Placed, centre: np.ndarray, parent: int | None) -> Placed:
    """``p`` turned 180° about the vertical line through ``centre``, with its partner class."""
    turn = rot_z(np.pi)
    t = p.t.copy()
    t[:2] = 2.0 * centre[:2] - p.t[:2]
    corners = np.array([[a, b, 0.0] for a in (p.lo[0], p.hi[0]) for b in (p.lo[1], p.hi[1])])
    moved = 2.0 * centre[:2] - corners[:, :2]
    lo = np.array([moved[:, 0].min(), moved[:, 1].min(), p.lo[2]])
    hi = np.array([moved[:, 0].max(), moved[:, 1].max(), p.hi[2]])
    name = p.mesh.class_name if p.mount == "ceiling" else TWIN_CLASS.get(p.mesh.class_name, p.mesh.class_name)
    mesh = replace(p.mesh, class_name=name)
    return replace(p, mesh=mesh, R=turn @ p.R, t=t, lo=lo, hi=hi, parent=parent)
