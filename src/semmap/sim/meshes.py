"""Procedural triangle meshes for each object class, built from convex parts with seeded variation.

Object frame: origin at the centre of the footprint on the floor, z up, the front faces -y and the back
(the side put against a wall) is the largest y. Builders take a ``numpy.random.Generator`` and optional sizes
(metres) and return an :class:`ObjectMesh`: the parts, their materials, the surfaces other objects may rest on,
and the rectangles of wall/floor the object hides (the scene cuts those out of the shell so the ground truth
has no invisible surfaces there).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from itertools import pairwise

import numpy as np

from semmap.errors import SimulationError
from semmap.sim.materials import (
    BRIGHTS,
    FABRICS,
    METALS,
    PAINTS,
    PLASTICS,
    RGB,
    WOODS,
    Material,
    jitter_color,
    pick,
)
from semmap.sim.primitives import Part, box, ellipsoid, frustum, limb, oriented_box, rot_x
from semmap.types import rot_z

#: Default free height above a surface with nothing over it (metres).
OPEN_CLEARANCE = 1.0


@dataclass(frozen=True)
class Surface:
    """Horizontal rectangle (object frame) where smaller objects may rest, with the free height above it."""

    x0: float
    x1: float
    y0: float
    y1: float
    z: float
    clear: float = OPEN_CLEARANCE
    kind: str = "top"  # "top", "compartment" (shelf), "seat" (sofa), "bed"


@dataclass
class ObjectMesh:
    """An object's parts (object frame), materials, support surfaces and the shell areas it hides."""

    class_name: str
    parts: list[Part]
    materials: list[Material]
    surfaces: list[Surface] = field(default_factory=list)
    wall_cover: tuple[float, float, float, float] | None = None  # (x0, x1, z0, z1) on the back plane
    floor_cover: tuple[float, float, float, float] | None = None  # (x0, x1, y0, y1) on z = 0

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Axis-aligned bounds (lo, hi) in the object frame."""
        V = np.concatenate([p.vertices for p in self.parts])
        return V.min(0), V.max(0)

    @property
    def n_triangles(self) -> int:
        return sum(len(p.triangles) for p in self.parts)


class _Kit:
    """Collects parts and materials while a builder runs."""

    def __init__(self, class_name: str, rng: np.random.Generator) -> None:
        self.class_name = class_name
        self.rng = rng
        self.parts: list[Part] = []
        self.materials: list[Material] = []

    def mat(self, pattern: str, color: RGB, color2: RGB = (0, 0, 0), *, tile_m: float = 0.5, size: int = 256,
            emissive: float = 0.0) -> int:
        """Slot of a new material with its own texture seed."""
        seed = int(self.rng.integers(2**31))
        self.materials.append(Material(pattern, color, color2, tile_m, seed, size, emissive))
        return len(self.materials) - 1

    def add(self, part: Part) -> Part:
        self.parts.append(part)
        return part

    def box(self, lo, hi, m: int, **kw) -> Part:
        return self.add(box(lo, hi, m, **kw))

    def done(self, **kw) -> ObjectMesh:
        return ObjectMesh(self.class_name, self.parts, self.materials, **kw)


def _u(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(rng.uniform(lo, hi))


# --------------------------------------------------------------------------------------------------
# furniture
# --------------------------------------------------------------------------------------------------
def table(rng: np.random.Generator, w: float | None = None, d: float | None = None, h: float | None = None,
          class_name: str = "table") -> ObjectMesh:
    """Four-legged table with an apron; dining, meeting or coffee table depending on the sizes."""
    k = _Kit(class_name, rng)
    w = w or _u(rng, 1.0, 1.6)
    d = d or _u(rng, 0.7, 0.9)
    h = h or _u(rng, 0.72, 0.76)
    tt = _u(rng, 0.03, 0.05)
    top = k.mat("wood", jitter_color(rng, pick(rng, WOODS)), tile_m=_u(rng, 0.5, 0.9))
    metal_legs = rng.random() < 0.35
    leg = k.mat("metal", pick(rng, METALS), tile_m=0.3) if metal_legs else top
    k.box((-w / 2, -d / 2, h - tt), (w / 2, d / 2, h), top)
    ls = _u(rng, 0.035, 0.06)
    inset = _u(rng, 0.03, 0.08)
    xs = (-w / 2 + inset, w / 2 - inset - ls)
    ys = (-d / 2 + inset, d / 2 - inset - ls)
    round_legs = rng.random() < 0.4
    for x in xs:
        for y in ys:
            if round_legs:
                k.add(frustum(ls / 2 * 0.7, ls / 2, 0.0, h - tt, leg, center=(x + ls / 2, y + ls / 2), segments=10))
            else:
                k.box((x, y, 0.0), (x + ls, y + ls, h - tt), leg)
    ah = min(0.09, h * 0.15)
    if h > 0.55:  # apron between the legs (not on coffee tables)
        k.box((xs[0] + ls, ys[0], h - tt - ah), (xs[1], ys[0] + 0.02, h - tt), leg)
        k.box((xs[0] + ls, ys[1] + ls - 0.02, h - tt - ah), (xs[1], ys[1] + ls, h - tt), leg)
        k.box((xs[0], ys[0] + ls, h - tt - ah), (xs[0] + 0.02, ys[1], h - tt), leg)
        k.box((xs[1] + ls - 0.02, ys[0] + ls, h - tt - ah), (xs[1] + ls, ys[1], h - tt), leg)
    elif rng.random() < 0.6:  # lower shelf of a coffee table
        k.box((xs[0] + ls, ys[0] + ls, 0.12), (xs[1], ys[1], 0.14), top)
    return k.done(surfaces=[Surface(-w / 2 + 0.03, w / 2 - 0.03, -d / 2 + 0.03, d / 2 - 0.03, h)])


def desk(rng: np.random.Generator, w: float | None = None, d: float | None = None,
         h: float | None = None) -> ObjectMesh:
    """Desk: top, a side panel, a drawer pedestal with handles, and a modesty panel at the back."""
    k = _Kit("desk", rng)
    w = w or _u(rng, 1.2, 1.6)
    d = d or _u(rng, 0.65, 0.8)
    h = h or _u(rng, 0.72, 0.76)
    tt = 0.025
    wood = k.mat("wood", jitter_color(rng, pick(rng, (*WOODS, (200, 200, 195), (90, 90, 95)))),
                 tile_m=_u(rng, 0.6, 1.0))
    body = k.mat("plastic", jitter_color(rng, pick(rng, ((210, 210, 205), (70, 70, 75), (150, 120, 90)))))
    handle = k.mat("metal", pick(rng, METALS), tile_m=0.2)
    k.box((-w / 2, -d / 2, h - tt), (w / 2, d / 2, h), wood)
    k.box((-w / 2 + 0.01, -d / 2 + 0.03, 0.0), (-w / 2 + 0.035, d / 2 - 0.01, h - tt), body)
    pw = _u(rng, 0.38, 0.45)
    px0 = w / 2 - 0.01 - pw
    k.box((px0, -d / 2 + 0.04, 0.0), (w / 2 - 0.01, d / 2 - 0.01, h - tt), body)
    n_drawers = int(rng.integers(2, 4))
    dh = (h - tt - 0.04) / n_drawers
    for i in range(n_drawers):
        z0 = 0.02 + i * dh
        k.box((px0 + 0.005, -d / 2 + 0.02, z0 + 0.004), (w / 2 - 0.015, -d / 2 + 0.04, z0 + dh - 0.004), wood)
        hz = z0 + dh * 0.7
        k.box((px0 + pw / 2 - 0.06, -d / 2 + 0.005, hz - 0.006), (px0 + pw / 2 + 0.06, -d / 2 + 0.02, hz + 0.006),
              handle)
    k.box((-w / 2 + 0.035, d / 2 - 0.06, 0.3), (px0, d / 2 - 0.045, h - tt), body)
    return k.done(surfaces=[Surface(-w / 2 + 0.03, w / 2 - 0.03, -d / 2 + 0.03, d / 2 - 0.03, h)])


def chair(rng: np.random.Generator, style: str | None = None) -> ObjectMesh:
    """Dining chair (legs, seat, back posts and slats) or office chair (star base, column, seat, back)."""
    style = style or ("office" if rng.random() < 0.5 else "dining")
    if style == "office":
        return _office_chair(rng)
    k = _Kit("chair", rng)
    sw, sd = _u(rng, 0.42, 0.48), _u(rng, 0.42, 0.48)
    sh = _u(rng, 0.44, 0.47)
    st = _u(rng, 0.03, 0.05)
    wood = k.mat("wood", jitter_color(rng, pick(rng, WOODS)), tile_m=0.4)
    seat = k.mat("fabric", jitter_color(rng, pick(rng, FABRICS)), tile_m=0.25) if rng.random() < 0.5 else wood
    ls = _u(rng, 0.03, 0.04)
    back_h = sh + _u(rng, 0.38, 0.5)
    for x in (-sw / 2, sw / 2 - ls):
        k.box((x, -sd / 2, 0.0), (x + ls, -sd / 2 + ls, sh - st), wood)
        k.box((x, sd / 2 - ls, 0.0), (x + ls, sd / 2, back_h), wood)
    k.box((-sw / 2, -sd / 2, sh - st), (sw / 2, sd / 2 - ls, sh), seat)
    rail = _u(rng, 0.07, 0.12)
    k.box((-sw / 2 + ls, sd / 2 - ls * 0.8, back_h - rail), (sw / 2 - ls, sd / 2 - ls * 0.2, back_h), wood)
    n_slats = int(rng.integers(2, 5))
    gap = (sw - 2 * ls) / (n_slats + 1)
    for i in range(n_slats):
        x = -sw / 2 + ls + gap * (i + 1)
        k.box((x - 0.012, sd / 2 - ls * 0.7, sh), (x + 0.012, sd / 2 - ls * 0.3, back_h - rail), wood)
    k.box((-sw / 2 + ls, -sd / 2 + 0.005, 0.12), (sw / 2 - ls, -sd / 2 + 0.02, 0.15), wood)  # stretcher
    return k.done()


def _office_chair(rng: np.random.Generator) -> ObjectMesh:
    k = _Kit("chair", rng)
    frame = k.mat("plastic", pick(rng, ((35, 35, 38), (60, 60, 65), (180, 180, 185))))
    cushion = k.mat("fabric", jitter_color(rng, pick(rng, FABRICS)), tile_m=0.2)
    metal = k.mat("metal", pick(rng, METALS), tile_m=0.2)
    r = _u(rng, 0.28, 0.32)
    for i in range(5):
        a = 2 * np.pi * i / 5 + np.pi / 2
        end = np.array([r * np.cos(a), r * np.sin(a), 0.055])
        k.add(oriented_box((0.0, 0.0, 0.07), end, 0.04, 0.03, frame))
        k.add(ellipsoid((0.025, 0.025, 0.025), end - (0, 0, 0.03), frame, n_lat=5, n_lon=8))
    sh = _u(rng, 0.45, 0.52)
    k.add(frustum(0.03, 0.03, 0.0, 0.09, frame, segments=10))
    k.add(frustum(0.022, 0.022, 0.09, sh - 0.09, metal, segments=10))
    sw, sd = _u(rng, 0.46, 0.52), _u(rng, 0.44, 0.5)
    k.box((-0.1, -0.1, sh - 0.1), (0.1, 0.1, sh - 0.08), frame)
    k.box((-sw / 2, -sd / 2, sh - 0.08), (sw / 2, sd / 2, sh), cushion)
    bh = _u(rng, 0.45, 0.6)
    bw = sw * _u(rng, 0.85, 0.95)
    yb = sd / 2 + 0.02
    k.box((-0.03, sd / 2 - 0.12, sh - 0.08), (0.03, yb + 0.04, sh - 0.06), frame)
    k.box((-0.03, yb + 0.02, sh - 0.06), (0.03, yb + 0.04, sh + 0.12), frame)
    k.box((-bw / 2, yb - 0.02, sh + 0.12), (bw / 2, yb + 0.05, sh + 0.12 + bh), cushion)
    if rng.random() < 0.6:  # armrests
        for x in (-sw / 2 - 0.03, sw / 2):
            k.box((x, -0.03, sh - 0.08), (x + 0.03, 0.0, sh + 0.18), frame)
            k.box((x - 0.005, -0.16, sh + 0.18), (x + 0.035, 0.1, sh + 0.21), frame)
    return k.done()


def sofa(rng: np.random.Generator, seats: int | None = None, class_name: str = "sofa") -> ObjectMesh:
    """Sofa or armchair: legs, base, seat and back cushions, back frame and arms."""
    k = _Kit(class_name, rng)
    seats = seats or int(rng.integers(2, 4))
    fab = jitter_color(rng, pick(rng, FABRICS))
    pattern = "leather" if rng.random() < 0.25 else "fabric"
    body = k.mat(pattern, fab, tile_m=0.4)
    cush = k.mat(pattern, jitter_color(rng, fab, 0.06), tile_m=0.3)
    legm = k.mat("wood", pick(rng, WOODS), tile_m=0.2)
    sw = _u(rng, 0.55, 0.65)
    aw = _u(rng, 0.14, 0.22)
    W = seats * sw + 2 * aw
    D = _u(rng, 0.82, 0.95)
    leg_h = _u(rng, 0.06, 0.1)
    base_top = _u(rng, 0.28, 0.32)
    seat_top = base_top + _u(rng, 0.12, 0.15)
    back_top = _u(rng, 0.78, 0.9)
    arm_top = _u(rng, 0.58, 0.66)
    bt = _u(rng, 0.14, 0.2)  # back frame thickness
    bc = _u(rng, 0.14, 0.18)  # back cushion thickness
    for x in (-W / 2 + 0.05, W / 2 - 0.05):
        for y in (-D / 2 + 0.05, D / 2 - 0.05):
            k.add(frustum(0.02, 0.025, 0.0, leg_h, legm, center=(x, y), segments=8))
    xi = W / 2 - aw
    k.box((-xi, -D / 2, leg_h), (xi, D / 2 - bt, base_top), body)
    k.box((-W / 2, D / 2 - bt, leg_h), (W / 2, D / 2, back_top), body)
    for s in (-1, 1):
        x0, x1 = sorted((s * xi, s * W / 2))
        k.box((x0, -D / 2, leg_h), (x1, D / 2 - bt, arm_top), body)
    y_back = D / 2 - bt - bc
    for i in range(seats):
        x0 = -xi + i * sw + 0.004
        x1 = -xi + (i + 1) * sw - 0.004
        k.box((x0, -D / 2 + 0.01, base_top), (x1, y_back - 0.004, seat_top), cush)
        k.box((x0, y_back, base_top), (x1, D / 2 - bt, back_top - 0.04), cush)
    seat = Surface(-xi + 0.01, xi - 0.01, -D / 2 + 0.02, y_back - 0.005, seat_top,
                   clear=back_top - seat_top - 0.05, kind="seat")
    return k.done(surfaces=[seat], wall_cover=(-W / 2, W / 2, leg_h, back_top))


def bed(rng: np.random.Generator, w: float | None = None, length: float | None = None) -> ObjectMesh:
    """Bed: legs, frame, mattress, blanket over the foot end, and a headboard against the wall."""
    k = _Kit("bed", rng)
    w = w or float(rng.choice([0.95, 1.45, 1.65]))
    L = length or _u(rng, 2.0, 2.15)
    wood = k.mat("wood", jitter_color(rng, pick(rng, WOODS)), tile_m=0.8)
    mattress = k.mat("fabric", (225, 222, 215), tile_m=0.3)
    blanket = k.mat("fabric", jitter_color(rng, pick(rng, FABRICS)), jitter_color(rng, pick(rng, FABRICS)),
                    tile_m=_u(rng, 0.4, 0.8))
    hb_t = 0.06
    hb_h = _u(rng, 0.9, 1.2)
    y_front, y_head = -L / 2, L / 2 - hb_t
    frame_top = _u(rng, 0.3, 0.36)
    m_top = frame_top + _u(rng, 0.18, 0.24)
    for x in (-w / 2 + 0.03, w / 2 - 0.06):
        for y in (y_front + 0.03, y_head - 0.06):
            k.box((x, y, 0.0), (x + 0.03, y + 0.03, 0.12), wood)
    k.box((-w / 2, y_front, 0.12), (w / 2, y_head, frame_top), wood)
    k.box((-w / 2 + 0.02, y_front + 0.02, frame_top), (w / 2 - 0.02, y_head, m_top), mattress)
    y_blanket = y_front + (y_head - y_front) * _u(rng, 0.62, 0.72)
    k.box((-w / 2 - 0.01, y_front - 0.01, frame_top - 0.08), (w / 2 + 0.01, y_blanket, m_top + 0.03), blanket)
    k.box((-w / 2, y_head, 0.0), (w / 2, L / 2, hb_h), wood)
    pillows = Surface(-w / 2 + 0.04, w / 2 - 0.04, y_blanket + 0.01, y_head, m_top, clear=0.5, kind="bed")
    return k.done(surfaces=[pillows], wall_cover=(-w / 2, w / 2, 0.0, hb_h))


def cabinet(rng: np.random.Generator, w: float | None = None, d: float | None = None, h: float | None = None,
            *, doors: int | None = None, drawers: int = 0, plinth: bool = True,
            class_name: str = "cabinet", top_material: Material | None = None) -> ObjectMesh:
    """Cabinet (wardrobe, sideboard, TV stand, nightstand, kitchen unit): body, plinth, door/drawer fronts."""
    k = _Kit(class_name, rng)
    w = w or _u(rng, 0.8, 1.2)
    d = d or _u(rng, 0.4, 0.6)
    h = h or _u(rng, 0.8, 2.0)
    doors = doors if doors is not None else (2 if w > 0.6 else 1)
    color = jitter_color(rng, pick(rng, WOODS + PAINTS[:3] + ((80, 80, 85),)))
    body = k.mat("wood" if rng.random() < 0.6 else "plastic", color, tile_m=_u(rng, 0.6, 1.0))
    front = k.mat("wood", jitter_color(rng, color, 0.05), tile_m=_u(rng, 0.5, 0.9))
    handle = k.mat("metal", pick(rng, METALS), tile_m=0.2)
    ft = 0.018
    pz = 0.08 if plinth else 0.0
    if plinth:
        k.box((-w / 2 + 0.01, -d / 2 + 0.05, 0.0), (w / 2 - 0.01, d / 2, pz), body)
    top_z = h
    if top_material is not None:
        k.materials.append(top_material)
        tm = len(k.materials) - 1
        k.box((-w / 2, -d / 2 - 0.02, h - 0.03), (w / 2, d / 2, h), tm)
        top_z = h - 0.03
    k.box((-w / 2, -d / 2 + ft, pz), (w / 2, d / 2, top_z), body)
    zf0, zf1 = pz + 0.003, top_z - 0.003
    y0, y1 = -d / 2, -d / 2 + ft
    z_split = zf1 - drawers * min(0.18, (zf1 - zf0) / max(drawers, 1))
    if drawers:
        dh = (zf1 - z_split) / drawers
        for i in range(drawers):
            z0 = z_split + i * dh
            k.box((-w / 2 + 0.003, y0, z0 + 0.002), (w / 2 - 0.003, y1, z0 + dh - 0.002), front)
            k.box((-0.06, y0 - 0.015, z0 + dh / 2 - 0.006), (0.06, y0, z0 + dh / 2 + 0.006), handle)
    if doors and z_split - zf0 > 0.1:
        dw = w / doors
        for i in range(doors):
            x0 = -w / 2 + i * dw
            k.box((x0 + 0.003, y0, zf0), (x0 + dw - 0.003, y1, z_split - 0.002), front)
            hx = x0 + dw - 0.04 if i % 2 == 0 else x0 + 0.03
            hz = min(z_split - 0.12, zf0 + 0.9) if h > 1.2 else z_split - 0.08
            k.box((hx, y0 - 0.02, hz - 0.06), (hx + 0.012, y0, hz + 0.06), handle)
    surfaces = [Surface(-w / 2 + 0.02, w / 2 - 0.02, -d / 2 + 0.03, d / 2 - 0.02, h)]
    floor = (-w / 2 + 0.01, w / 2 - 0.01, -d / 2 + 0.05, d / 2) if plinth else None
    return k.done(surfaces=surfaces, wall_cover=(-w / 2, w / 2, 0.0, h), floor_cover=floor)


def shelf(rng: np.random.Generator, w: float | None = None, d: float | None = None, h: float | None = None,
          boards: int | None = None) -> ObjectMesh:
    """Bookshelf: plinth, sides, top, back panel and shelf boards; each compartment is a surface for books."""
    k = _Kit("shelf", rng)
    w = w or _u(rng, 0.7, 1.2)
    d = d or _u(rng, 0.28, 0.38)
    h = h or _u(rng, 1.2, 2.0)
    n = boards or max(2, round((h - 0.1) / _u(rng, 0.32, 0.4)))
    wood = k.mat("wood", jitter_color(rng, pick(rng, (*WOODS, (220, 220, 215), (50, 50, 55)))),
                 tile_m=_u(rng, 0.6, 1.0))
    back = k.mat("wood", jitter_color(rng, pick(rng, WOODS)), tile_m=0.8)
    t, bt, pz = 0.018, 0.008, 0.06
    k.box((-w / 2, -d / 2, 0.0), (w / 2, d / 2, pz), wood)
    k.box((-w / 2, -d / 2, pz), (-w / 2 + t, d / 2, h), wood)
    k.box((w / 2 - t, -d / 2, pz), (w / 2, d / 2, h), wood)
    k.box((-w / 2 + t, -d / 2, h - t), (w / 2 - t, d / 2, h), wood)
    k.box((-w / 2 + t, d / 2 - bt, pz), (w / 2 - t, d / 2, h - t), back)
    levels = np.linspace(pz, h - t, n + 1)
    surfaces = []
    for i, z in enumerate(levels[:-1]):
        z_top = z if i == 0 else z + t
        if i > 0:
            k.box((-w / 2 + t, -d / 2 + 0.01, z), (w / 2 - t, d / 2 - bt, z + t), wood)
        z_next = levels[i + 1]
        surfaces.append(Surface(-w / 2 + t, w / 2 - t, -d / 2 + 0.015, d / 2 - bt, z_top,
                                clear=z_next - z_top, kind="compartment"))
    return k.done(surfaces=surfaces, wall_cover=(-w / 2, w / 2, 0.0, h), floor_cover=(-w / 2, w / 2, -d / 2, d / 2))


def refrigerator(rng: np.random.Generator) -> ObjectMesh:
    """Fridge-freezer: body, two doors with a gap, vertical handles."""
    k = _Kit("refrigerator", rng)
    w, d, h = _u(rng, 0.6, 0.75), _u(rng, 0.62, 0.7), _u(rng, 1.7, 1.9)
    color = pick(rng, ((225, 225, 222), (170, 172, 175), (40, 40, 42)))
    body = k.mat("metal" if color[0] < 200 else "porcelain", color, tile_m=0.8)
    handle = k.mat("metal", pick(rng, METALS), tile_m=0.2)
    ft = 0.05
    k.box((-w / 2, -d / 2 + ft, 0.0), (w / 2, d / 2, h), body)
    split = h * _u(rng, 0.3, 0.4)
    for z0, z1 in ((0.02, split - 0.005), (split + 0.005, h - 0.005)):
        k.box((-w / 2 + 0.003, -d / 2, z0), (w / 2 - 0.003, -d / 2 + ft, z1), body)
        k.box((w / 2 - 0.07, -d / 2 - 0.035, z0 + 0.05), (w / 2 - 0.05, -d / 2, min(z1 - 0.05, z0 + 0.6)), handle)
    return k.done(surfaces=[Surface(-w / 2 + 0.02, w / 2 - 0.02, -d / 2 + 0.05, d / 2 - 0.02, h)],
                  wall_cover=(-w / 2, w / 2, 0.0, h), floor_cover=(-w / 2, w / 2, -d / 2 + ft, d / 2))


def counter(rng: np.random.Generator, w: float | None = None) -> ObjectMesh:
    """Kitchen counter: base units with doors and drawers under a granite top."""
    top = Material("granite", jitter_color(rng, pick(rng, ((90, 90, 95), (200, 195, 185), (60, 50, 45)))),
                   (30, 30, 30), 0.5, int(rng.integers(2**31)))
    mesh = cabinet(rng, w or _u(rng, 1.2, 2.4), 0.6, 0.9, doors=None, drawers=1, class_name="counter",
                   top_material=top)
    return mesh


def sink(rng: np.random.Generator) -> ObjectMesh:
    """Sink unit standing on a counter: steel basin (open top) and a faucet."""
    k = _Kit("sink", rng)
    steel = k.mat("metal", (185, 188, 192), tile_m=0.3)
    w, d, h, t = _u(rng, 0.45, 0.6), _u(rng, 0.38, 0.45), 0.1, 0.015
    k.box((-w / 2, -d / 2, 0.0), (w / 2, d / 2, t), steel)
    k.box((-w / 2, -d / 2, t), (-w / 2 + t, d / 2, h), steel)
    k.box((w / 2 - t, -d / 2, t), (w / 2, d / 2, h), steel)
    k.box((-w / 2 + t, -d / 2, t), (w / 2 - t, -d / 2 + t, h), steel)
    k.box((-w / 2 + t, d / 2 - 0.06, t), (w / 2 - t, d / 2, h), steel)
    yb = d / 2 - 0.03
    top = h + _u(rng, 0.18, 0.26)
    k.add(frustum(0.018, 0.014, h, top, steel, center=(0.0, yb), segments=10))
    k.add(limb((0.0, yb, top - 0.01), (0.0, yb - 0.16, top - 0.02), 0.012, 0.01, steel, segments=8))
    return k.done()


# --------------------------------------------------------------------------------------------------
# things on desks, tables and shelves
# --------------------------------------------------------------------------------------------------
def monitor(rng: np.random.Generator, w: float | None = None, tv: bool = False) -> ObjectMesh:
    """Flat screen on a stand: base plate, neck, bezel panel and an emissive screen with content."""
    k = _Kit("monitor", rng)
    w = w or (_u(rng, 0.9, 1.3) if tv else _u(rng, 0.5, 0.65))
    bezel = 0.012 if tv else _u(rng, 0.01, 0.02)
    sh = w * 9 / 16 + 2 * bezel
    pd = _u(rng, 0.03, 0.05) if tv else _u(rng, 0.02, 0.035)
    frame = k.mat("plastic", pick(rng, ((25, 25, 28), (35, 35, 40), (190, 190, 190))))
    screen = k.mat("screen", pick(rng, ((20, 30, 60), (30, 60, 90), (60, 30, 60), (20, 60, 40))), tile_m=1.0,
                   emissive=0.45)
    base_w, base_d = (0.5 * w, 0.22) if tv else (_u(rng, 0.2, 0.26), _u(rng, 0.16, 0.2))
    k.box((-base_w / 2, -base_d / 2, 0.0), (base_w / 2, base_d / 2, 0.015), frame)
    z0 = _u(rng, 0.06, 0.12) if tv else _u(rng, 0.08, 0.16)
    yc = 0.0
    k.box((-0.03, yc + 0.01, 0.015), (0.03, yc + 0.04, z0 + sh / 2), frame)
    k.box((-w / 2 - bezel, yc - pd + 0.01, z0), (w / 2 + bezel, yc + 0.01, z0 + sh), frame)
    k.box((-w / 2, yc - pd + 0.008, z0 + bezel), (w / 2, yc - pd + 0.01, z0 + sh - bezel), screen, fit=True)
    return k.done()


def keyboard(rng: np.random.Generator) -> ObjectMesh:
    """Keyboard: base plate and individual key caps with glyph marks."""
    k = _Kit("keyboard", rng)
    dark = rng.random() < 0.7
    base_c = (30, 30, 33) if dark else (215, 215, 210)
    base = k.mat("plastic", base_c)
    caps = [k.mat("keycap", (45, 45, 50) if dark else (235, 235, 230), (200, 200, 200) if dark else (40, 40, 45),
                  tile_m=1.0, size=32) for _ in range(4)]
    pitch, key, rows = 0.019, 0.0165, 5
    cols = int(rng.integers(14, 16))
    W, D = cols * pitch + 0.02, rows * pitch + pitch + 0.02
    k.box((-W / 2, -D / 2, 0.0), (W / 2, D / 2, 0.018), base)
    y_top = D / 2 - 0.01 - pitch
    for r in range(rows):
        y = y_top - r * pitch
        for c in range(cols):
            x = -W / 2 + 0.01 + c * pitch
            k.box((x + 0.001, y - key, 0.018), (x + key + 0.001, y, 0.026), caps[(r * 7 + c * 3) % 4], fit=True)
    y = y_top - rows * pitch
    k.box((-W / 2 + 0.01 + 4 * pitch, y - key, 0.018), (-W / 2 + 0.01 + 10 * pitch, y, 0.026), caps[0], fit=True)
    return k.done()


def book(rng: np.random.Generator, thickness: float | None = None, height: float | None = None,
         depth: float | None = None) -> ObjectMesh:
    """Book standing upright: thickness along x, depth along y, height along z; spine faces -y."""
    k = _Kit("book", rng)
    t = thickness or _u(rng, 0.015, 0.05)
    h = height or _u(rng, 0.18, 0.28)
    d = depth or _u(rng, 0.13, 0.2)
    m = k.mat("book", jitter_color(rng, pick(rng, BRIGHTS), 0.15), tile_m=h, size=64)
    k.box((-t / 2, -d / 2, 0.0), (t / 2, d / 2, h), m)
    return k.done()


def cup(rng: np.random.Generator) -> ObjectMesh:
    """Mug: tapered body, coffee surface and a C-shaped handle."""
    k = _Kit("cup", rng)
    rb, rt, h = _u(rng, 0.03, 0.036), _u(rng, 0.037, 0.045), _u(rng, 0.085, 0.11)
    body = k.mat("porcelain", jitter_color(rng, pick(rng, BRIGHTS + ((235, 235, 230),) * 3), 0.05))
    coffee = k.mat("plastic", (60, 35, 20))
    k.add(frustum(rb, rt, 0.0, h, body, segments=18))
    k.add(frustum(rt - 0.004, rt - 0.004, h, h + 0.001, coffee, segments=18))
    hx0 = rb + (rt - rb) * 0.3
    k.box((hx0 - 0.004, -0.006, h * 0.75), (hx0 + 0.03, 0.006, h * 0.75 + 0.01), body)
    k.box((hx0 + 0.02, -0.006, h * 0.2), (hx0 + 0.03, 0.006, h * 0.75), body)
    k.box((hx0 - 0.006, -0.006, h * 0.2), (hx0 + 0.02, 0.006, h * 0.2 + 0.01), body)
    return k.done()


def bottle(rng: np.random.Generator) -> ObjectMesh:
    """Bottle: body, label band, shoulder, neck and cap."""
    k = _Kit("bottle", rng)
    r, h = _u(rng, 0.028, 0.04), _u(rng, 0.14, 0.22)
    rn = _u(rng, 0.011, 0.015)
    glass = k.mat("plastic", pick(rng, ((40, 90, 50), (110, 60, 25), (120, 160, 190), (200, 200, 205),
                                         (180, 40, 40))))
    label = k.mat("book", jitter_color(rng, pick(rng, BRIGHTS)), tile_m=h * 0.5, size=64)
    cap = k.mat("plastic", pick(rng, PLASTICS))
    k.add(frustum(r, r, 0.0, h, glass, segments=18))
    k.add(frustum(r + 0.001, r + 0.001, h * 0.3, h * 0.75, label, segments=18))
    sh = _u(rng, 0.03, 0.05)
    k.add(frustum(r, rn, h, h + sh, glass, segments=18))
    nh = _u(rng, 0.03, 0.06)
    k.add(frustum(rn, rn, h + sh, h + sh + nh, glass, segments=12))
    k.add(frustum(rn + 0.002, rn + 0.002, h + sh + nh, h + sh + nh + 0.02, cap, segments=12))
    return k.done()


def plant(rng: np.random.Generator, tall: bool | None = None) -> ObjectMesh:
    """Potted plant: pot, soil, stems and a cluster of leafy blobs (floor or desk size)."""
    k = _Kit("plant", rng)
    tall = bool(rng.random() < 0.5) if tall is None else tall
    s = 1.0 if tall else _u(rng, 0.3, 0.4)
    pot = k.mat("porcelain" if rng.random() < 0.5 else "plastic",
                jitter_color(rng, pick(rng, ((170, 90, 60), (230, 230, 225), (60, 60, 65), (90, 120, 150)))))
    soil = k.mat("soil", (70, 50, 35), tile_m=0.2)
    green = jitter_color(rng, pick(rng, ((50, 120, 50), (70, 140, 60), (40, 100, 60))), 0.1)
    leaf = k.mat("foliage", green, tile_m=0.15 * max(s, 0.5))
    stem = k.mat("wood", (90, 70, 40), tile_m=0.2)
    rb, rt, ph = 0.11 * s * _u(rng, 0.8, 1.2), 0.15 * s * _u(rng, 0.85, 1.2), 0.3 * s * _u(rng, 0.8, 1.2)
    rt = max(rt, rb + 0.01)
    k.add(frustum(rb, rt, 0.0, ph, pot, segments=16))
    k.add(frustum(rt - 0.01, rt - 0.01, ph, ph + 0.004, soil, segments=16))
    top = ph + (_u(rng, 0.5, 1.1) if tall else _u(rng, 0.12, 0.22))
    n_blobs = int(rng.integers(6, 13))
    for _ in range(n_blobs):
        ang = rng.uniform(0, 2 * np.pi)
        rad = rng.uniform(0.0, rt * 1.3)
        z = rng.uniform(ph + (top - ph) * 0.45, top)
        radii = np.array([rng.uniform(0.08, 0.18), rng.uniform(0.08, 0.18), rng.uniform(0.06, 0.14)]) * s
        c = np.array([rad * np.cos(ang), rad * np.sin(ang), min(z, top - radii[2])])
        k.add(limb((0.0, 0.0, ph), c, 0.008 * max(s, 0.5), 0.005 * max(s, 0.5), stem, segments=6))
        k.add(ellipsoid(radii, c, leaf, R=rot_z(rng.uniform(0, np.pi)), n_lat=6, n_lon=10))
    return k.done()


def lamp(rng: np.random.Generator, kind: str | None = None) -> ObjectMesh:
    """Desk lamp (base, two-segment arm, tilted shade) or floor lamp (base, pole, shade)."""
    k = _Kit("lamp", rng)
    kind = kind or ("floor" if rng.random() < 0.5 else "desk")
    metal = k.mat("metal", pick(rng, METALS), tile_m=0.3)
    shade = k.mat("fabric", jitter_color(rng, pick(rng, ((235, 225, 200), (200, 190, 160), (60, 60, 65)))),
                  tile_m=0.2, emissive=0.25)
    if kind == "floor":
        H = _u(rng, 1.45, 1.7)
        k.add(frustum(0.15, 0.13, 0.0, 0.03, metal, segments=18))
        k.add(frustum(0.012, 0.012, 0.03, H - 0.25, metal, segments=8))
        k.add(frustum(0.2, 0.13, H - 0.28, H, shade, segments=20))
        return k.done()
    k.add(frustum(0.07, 0.06, 0.0, 0.025, metal, segments=16))
    elbow = np.array([0.0, 0.08, _u(rng, 0.3, 0.4)])
    head = np.array([0.0, -0.12, elbow[2] + _u(rng, 0.02, 0.08)])
    k.add(limb((0.0, 0.0, 0.025), elbow, 0.01, 0.01, metal, segments=8))
    k.add(limb(elbow, head, 0.009, 0.009, metal, segments=8))
    tip = head + np.array([0.0, -0.06, -0.13])
    k.add(limb(head, tip, 0.025, 0.075, shade, segments=16))
    return k.done()


def picture(rng: np.random.Generator, w: float | None = None, h: float | None = None) -> ObjectMesh:
    """Framed picture or poster hanging on a wall; back plane at y = 0, bottom at z = 0."""
    k = _Kit("picture", rng)
    w = w or _u(rng, 0.4, 1.0)
    h = h or w * _u(rng, 0.6, 1.4)
    fb, fd = _u(rng, 0.015, 0.05), _u(rng, 0.02, 0.035)
    frame = k.mat("wood" if rng.random() < 0.5 else "metal", pick(rng, WOODS + METALS), tile_m=0.3)
    bg = jitter_color(rng, pick(rng, PAINTS + BRIGHTS[:4]), 0.1)
    canvas = k.mat("poster", bg, tile_m=1.0, size=256)
    k.box((-w / 2, -fd, 0.0), (-w / 2 + fb, 0.0, h), frame)
    k.box((w / 2 - fb, -fd, 0.0), (w / 2, 0.0, h), frame)
    k.box((-w / 2 + fb, -fd, 0.0), (w / 2 - fb, 0.0, fb), frame)
    k.box((-w / 2 + fb, -fd, h - fb), (w / 2 - fb, 0.0, h), frame)
    k.box((-w / 2 + fb, -fd + 0.006, fb), (w / 2 - fb, 0.0, h - fb), canvas, fit=True)
    return k.done(wall_cover=(-w / 2, w / 2, 0.0, h))


def whiteboard(rng: np.random.Generator, w: float | None = None) -> ObjectMesh:
    """Whiteboard with an aluminium frame and a pen tray; back plane at y = 0, bottom at z = 0."""
    k = _Kit("whiteboard", rng)
    w = w or _u(rng, 1.2, 1.8)
    h = _u(rng, 0.9, 1.2)
    alu = k.mat("metal", (190, 192, 195), tile_m=0.3)
    board = k.mat("whiteboard", (238, 238, 235), tile_m=1.0, size=256)
    f = 0.02
    k.box((-w / 2, -0.025, 0.0), (w / 2, 0.0, f), alu)
    k.box((-w / 2, -0.025, h - f), (w / 2, 0.0, h), alu)
    k.box((-w / 2, -0.025, f), (-w / 2 + f, 0.0, h - f), alu)
    k.box((w / 2 - f, -0.025, f), (w / 2, 0.0, h - f), alu)
    k.box((-w / 2 + f, -0.02, f), (w / 2 - f, 0.0, h - f), board, fit=True)
    k.box((-w / 2 + 0.1, -0.08, 0.0), (w / 2 - 0.1, -0.025, 0.015), alu)
    return k.done(wall_cover=(-w / 2, w / 2, 0.0, h))


def pillow(rng: np.random.Generator, lying: bool = False, w: float | None = None) -> ObjectMesh:
    """Cushion or bed pillow: a flattened ellipsoid, upright (leaning back) or lying flat."""
    k = _Kit("pillow", rng)
    w = w or _u(rng, 0.35, 0.5)
    h = w * _u(rng, 0.75, 1.0) if not lying else _u(rng, 0.35, 0.45)
    t = _u(rng, 0.1, 0.15)
    m = k.mat("fabric", jitter_color(rng, pick(rng, (*FABRICS, (230, 228, 220)))),
              jitter_color(rng, pick(rng, FABRICS)) if rng.random() < 0.4 else (0, 0, 0), tile_m=0.25)
    if lying:
        part = ellipsoid((w / 2, h / 2, t / 2), (0.0, 0.0, t / 2), m, n_lat=8, n_lon=18)
    else:
        part = ellipsoid((w / 2, t / 2, h / 2), (0.0, 0.0, 0.0), m, R=rot_x(-0.25), n_lat=8, n_lon=18)
        lo = part.vertices.min(0)
        part = part.transformed(np.eye(3), (0.0, 0.0, -lo[2]))
    k.add(part)
    return k.done()


def carton(rng: np.random.Generator, size=None) -> ObjectMesh:
    """Cardboard box with a slightly wider lid."""
    k = _Kit("box", rng)
    sx, sy, sz = size if size is not None else (_u(rng, 0.25, 0.6), _u(rng, 0.25, 0.5), _u(rng, 0.2, 0.45))
    m = k.mat("cardboard", jitter_color(rng, (170, 130, 85), 0.08), (195, 170, 120), tile_m=max(sx, sy), size=128)
    k.box((-sx / 2, -sy / 2, 0.0), (sx / 2, sy / 2, sz - 0.02), m)
    k.box((-sx / 2 - 0.004, -sy / 2 - 0.004, sz - 0.04), (sx / 2 + 0.004, sy / 2 + 0.004, sz), m)
    return k.done(surfaces=[Surface(-sx / 2, sx / 2, -sy / 2, sy / 2, sz)])


def person(rng: np.random.Generator, height: float | None = None) -> ObjectMesh:
    """Standing person: shoes, legs, hips, torso, arms with elbows, hands, neck, head and hair."""
    k = _Kit("person", rng)
    H = height or _u(rng, 1.55, 1.9)
    skin = k.mat("skin", pick(rng, ((230, 190, 160), (200, 150, 110), (140, 95, 65), (95, 65, 45))))
    shirt = k.mat("fabric", jitter_color(rng, pick(rng, FABRICS + BRIGHTS[:6])), tile_m=0.2)
    pants = k.mat("fabric", jitter_color(rng, pick(rng, ((40, 50, 80), (60, 60, 60), (120, 100, 80)))),
                  tile_m=0.2)
    shoe = k.mat("leather", pick(rng, ((30, 25, 20), (90, 60, 40), (220, 220, 215))))
    hair = k.mat("fabric", pick(rng, ((30, 20, 15), (90, 60, 30), (160, 130, 80), (60, 60, 60))), tile_m=0.1)
    hip_z, knee_z = 0.53 * H, 0.285 * H
    shoulder_z = 0.82 * H
    hw = 0.095 * H / 1.75
    stance = _u(rng, -0.08, 0.08)
    for s in (-1, 1):
        fx = s * hw
        fy = stance * s
        k.box((fx - 0.045, fy - 0.14, 0.0), (fx + 0.045, fy + 0.06, 0.07), shoe)
        k.add(limb((fx, fy, 0.07), (fx, fy * 0.5, knee_z), 0.045, 0.055, pants))
        k.add(limb((fx, fy * 0.5, knee_z), (fx * 0.9, 0.0, hip_z), 0.055, 0.075, pants))
    k.add(ellipsoid((0.17 * H / 1.75, 0.1, 0.09), (0.0, 0.0, hip_z), pants, n_lat=6, n_lon=12))
    torso_h = shoulder_z - hip_z
    k.add(ellipsoid((0.19 * H / 1.75, 0.115, torso_h * 0.6), (0.0, 0.0, hip_z + torso_h * 0.55), shirt,
                    n_lat=8, n_lon=14))
    sw = 0.2 * H / 1.75
    for s in (-1, 1):
        swing = rng.uniform(-0.35, 0.35)
        bend = rng.uniform(0.0, 1.0)
        shoulder = np.array([s * sw, 0.0, shoulder_z - 0.03])
        upper = 0.17 * H
        elbow = shoulder + upper * np.array([s * 0.12, -np.sin(swing), -np.cos(swing)])
        fore = 0.15 * H
        a = swing + bend
        wrist = elbow + fore * np.array([s * 0.05, -np.sin(a), -np.cos(a)])
        k.add(limb(shoulder, elbow, 0.045, 0.038, shirt))
        k.add(limb(elbow, wrist, 0.035, 0.028, skin if rng.random() < 0.5 else shirt))
        k.add(ellipsoid((0.025, 0.04, 0.05), wrist + (wrist - elbow) / fore * 0.045, skin, n_lat=5, n_lon=8))
    k.add(limb((0.0, 0.0, shoulder_z - 0.02), (0.0, 0.0, 0.87 * H), 0.045, 0.04, skin))
    head_c = np.array([0.0, -0.01, 0.93 * H])
    k.add(ellipsoid((0.075, 0.09, 0.11), head_c, skin, n_lat=8, n_lon=14))
    k.add(ellipsoid((0.08, 0.095, 0.075), head_c + np.array([0.0, 0.015, 0.045]), hair, n_lat=6, n_lon=14))
    return k.done()


# --------------------------------------------------------------------------------------------------
# doors, windows, curtains
# --------------------------------------------------------------------------------------------------
def door(rng: np.random.Generator, w: float | None = None, h: float | None = None) -> ObjectMesh:
    """Closed door set into a wall: leaf (in the wall opening), casing around it and a lever handle.

    Back plane y = 0 is the wall surface; the scene cuts the covered rectangle out of the wall.
    """
    k = _Kit("door", rng)
    w = w or _u(rng, 0.8, 0.95)
    h = h or _u(rng, 2.0, 2.1)
    paint = jitter_color(rng, pick(rng, PAINTS + WOODS[:3]), 0.05)
    leaf = k.mat("wood" if paint in WOODS else "paint", paint, tile_m=1.0)
    casing = k.mat("paint", jitter_color(rng, (235, 235, 230), 0.03), tile_m=1.0)
    metal = k.mat("metal", pick(rng, METALS), tile_m=0.1)
    c = 0.06
    k.box((-w / 2, -0.035, 0.0), (w / 2, 0.0, h), leaf)
    k.box((-w / 2 + 0.1, -0.04, 0.25), (w / 2 - 0.1, -0.035, h * 0.45), leaf)  # raised panels
    k.box((-w / 2 + 0.1, -0.04, h * 0.5), (w / 2 - 0.1, -0.035, h - 0.2), leaf)
    k.box((-w / 2 - c, -0.015, 0.0), (-w / 2, 0.0, h + c), casing)
    k.box((w / 2, -0.015, 0.0), (w / 2 + c, 0.0, h + c), casing)
    k.box((-w / 2, -0.015, h), (w / 2, 0.0, h + c), casing)
    hx = w / 2 - 0.08
    k.add(frustum(0.025, 0.025, 0.0, 0.02, metal, segments=10).transformed(rot_x(np.pi / 2), (hx, -0.035, 1.0)))
    k.box((hx - 0.12, -0.085, 0.99), (hx, -0.065, 1.01), metal)
    k.box((hx - 0.01, -0.065, 0.99), (hx + 0.01, -0.055, 1.01), metal)
    return k.done(wall_cover=(-w / 2 - c, w / 2 + c, 0.0, h + c))


def doorway(rng: np.random.Generator, w: float, h: float, wall_t: float, hinge: int = 1) -> ObjectMesh:
    """Open door between two rooms: jamb linings through the wall (y in [0, wall_t]), casings, open leaf.

    The leaf hangs on the ``hinge`` side (+1: +x jamb, -1: -x jamb), opened 90 degrees into y < 0.
    """
    k = _Kit("door", rng)
    paint = jitter_color(rng, pick(rng, PAINTS + WOODS[:3]), 0.05)
    leaf = k.mat("wood" if paint in WOODS else "paint", paint, tile_m=1.0)
    casing = k.mat("paint", jitter_color(rng, (235, 235, 230), 0.03), tile_m=1.0)
    metal = k.mat("metal", pick(rng, METALS), tile_m=0.1)
    j, c = 0.02, 0.06
    k.box((-w / 2, 0.0, 0.0), (-w / 2 + j, wall_t, h), casing)
    k.box((w / 2 - j, 0.0, 0.0), (w / 2, wall_t, h), casing)
    k.box((-w / 2 + j, 0.0, h - j), (w / 2 - j, wall_t, h), casing)
    for y0, y1 in ((-0.015, 0.0), (wall_t, wall_t + 0.015)):
        k.box((-w / 2 - c, y0, 0.0), (-w / 2, y1, h + c), casing)
        k.box((w / 2, y0, 0.0), (w / 2 + c, y1, h + c), casing)
        k.box((-w / 2, y0, h), (w / 2, y1, h + c), casing)
    lw = w - 2 * j - 0.006
    x_h = hinge * (w / 2 - j)
    xs = sorted((x_h, x_h - hinge * 0.04))
    k.box((xs[0], -lw - 0.016, 0.01), (xs[1], -0.016, h - j - 0.003), leaf)
    k.box((xs[0] - 0.04, -lw + 0.06, 0.99), (xs[1] + 0.04, -lw + 0.08, 1.01), metal)
    return k.done()


def window(rng: np.random.Generator, w: float | None = None, h: float | None = None) -> ObjectMesh:
    """Window on a wall: frame, mullions, an emissive outdoor view as the pane and a sill board.

    Back plane y = 0 is the wall surface, z = 0 the bottom of the frame (the sill sits just below).
    """
    k = _Kit("window", rng)
    w = w or _u(rng, 0.9, 1.8)
    h = h or _u(rng, 1.0, 1.5)
    frame = k.mat("paint", jitter_color(rng, pick(rng, ((235, 235, 232), (60, 60, 62), (150, 110, 70))), 0.03),
                  tile_m=1.0)
    view = k.mat("sky", (0, 0, 0), tile_m=1.0, size=256, emissive=0.7)
    sill = k.mat("wood", jitter_color(rng, pick(rng, WOODS)), tile_m=0.8)
    f, fd = _u(rng, 0.05, 0.08), _u(rng, 0.05, 0.07)
    k.box((-w / 2, -0.01, f), (w / 2, 0.0, h - f), view, fit=True)
    k.box((-w / 2, -fd, 0.0), (w / 2, 0.0, f), frame)
    k.box((-w / 2, -fd, h - f), (w / 2, 0.0, h), frame)
    k.box((-w / 2, -fd, f), (-w / 2 + f, 0.0, h - f), frame)
    k.box((w / 2 - f, -fd, f), (w / 2, 0.0, h - f), frame)
    n_panes = 2 if w > 1.1 else 1
    for i in range(1, n_panes):
        x = -w / 2 + i * w / n_panes
        k.box((x - f / 3, -fd * 0.8, f), (x + f / 3, -0.01, h - f), frame)
    if rng.random() < 0.5:
        z = h * _u(rng, 0.6, 0.7)
        k.box((-w / 2 + f, -fd * 0.8, z - f / 4), (w / 2 - f, -0.01, z + f / 4), frame)
    k.box((-w / 2 - 0.05, -0.15, -0.03), (w / 2 + 0.05, 0.0, 0.0), sill)
    return k.done(wall_cover=(-w / 2, w / 2, 0.0, h))


def curtain(rng: np.random.Generator, w: float | None = None, h: float | None = None) -> ObjectMesh:
    """Pleated curtain panel hanging beside a window (zig-zag of thin cloth strips), back at y = 0."""
    k = _Kit("curtain", rng)
    w = w or _u(rng, 0.3, 0.5)
    h = h or 2.3
    cloth = k.mat("fabric", jitter_color(rng, pick(rng, FABRICS + PAINTS[:2])), tile_m=0.3)
    n = max(3, round(w / 0.07))
    step = w / n
    depth = 0.06
    pts = [(-w / 2 + i * step, -depth * (i % 2)) for i in range(n + 1)]
    for (x0, y0), (x1, y1) in pairwise(pts):
        k.add(_strip(x0, y0 - 0.02, x1, y1 - 0.02, 0.03, h, cloth))
    return k.done()


def _strip(x0: float, y0: float, x1: float, y1: float, z0: float, z1: float, m: int, t: float = 0.008) -> Part:
    """Thin vertical cloth strip from (x0, y0) to (x1, y1) between heights z0 and z1."""
    dx, dy = x1 - x0, y1 - y0
    L = float(np.hypot(dx, dy))
    part = box((0.0, -t / 2, z0), (L, t / 2, z1), m)
    return part.transformed(rot_z(float(np.arctan2(dy, dx))), (x0, y0, 0.0))


def ceiling_light(rng: np.random.Generator, panel: bool | None = None) -> ObjectMesh:
    """Ceiling light: square office panel or round dome, top at local z = its height (mounted on the ceiling)."""
    k = _Kit("lamp", rng)
    panel = bool(rng.random() < 0.5) if panel is None else panel
    rim = k.mat("metal", (200, 200, 202), tile_m=0.3)
    glow = k.mat("porcelain", (250, 248, 240), emissive=0.9)
    if panel:
        s = float(rng.choice([0.6, 0.62]))
        k.box((-s / 2, -s / 2, 0.0), (s / 2, s / 2, 0.05), rim)
        k.box((-s / 2 + 0.03, -s / 2 + 0.03, -0.002), (s / 2 - 0.03, s / 2 - 0.03, 0.0), glow)
    else:
        r = _u(rng, 0.15, 0.22)
        k.add(frustum(r * 0.6, r, 0.0, 0.07, glow, segments=20))
        k.add(frustum(r + 0.02, r + 0.02, 0.07, 0.09, rim, segments=20))
    return k.done()


#: Builders by name; the scene picks them by the role an object plays.
BUILDERS: dict[str, Callable[..., ObjectMesh]] = {
    "table": table, "desk": desk, "chair": chair, "sofa": sofa, "bed": bed, "cabinet": cabinet,
    "shelf": shelf, "refrigerator": refrigerator, "counter": counter, "sink": sink, "monitor": monitor,
    "keyboard": keyboard, "book": book, "cup": cup, "bottle": bottle, "plant": plant, "lamp": lamp,
    "picture": picture, "whiteboard": whiteboard, "pillow": pillow, "box": carton, "person": person,
    "door": door, "window": window, "curtain": curtain, "ceiling_light": ceiling_light,
}


def build(name: str, rng: np.random.Generator, **kwargs) -> ObjectMesh:
    """Run the builder ``name`` (see :data:`BUILDERS`)."""
    try:
        builder = BUILDERS[name]
    except KeyError:
        raise SimulationError(f"no mesh builder for {name!r}; known: {', '.join(sorted(BUILDERS))}") from None
    return builder(rng, **kwargs)
