"""Furnishing recipes per room kind: which objects go where (desks with chairs and monitors, shelves with
books, sofas with pillows, beds with nightstands, counters with a sink, ...)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from semmap.sim import meshes
from semmap.sim.layout import Layout, rotated_bounds
from semmap.sim.meshes import ObjectMesh, Surface

#: (min, max) counts per room size, drawn uniformly (inclusive).
Counts = dict[str, tuple[int, int]]


class _Room:
    """What a recipe needs: the layout, the room index, the generator and the room size class."""

    def __init__(self, layout: Layout, room: int, size: str) -> None:
        self.layout = layout
        self.room = room
        self.rng = layout.rng
        self.size = size

    def n(self, counts: Counts) -> int:
        lo, hi = counts[self.size]
        return int(self.rng.integers(lo, hi + 1))

    def chance(self, p: float) -> bool:
        return bool(self.rng.random() < p)

    def u(self, lo: float, hi: float) -> float:
        return float(self.rng.uniform(lo, hi))

    def make(self, name: str, **kw) -> ObjectMesh:
        return meshes.build(name, self.rng, **kw)

    def wall(self, name_or_mesh: str | ObjectMesh, **kw) -> int | None:
        mesh = self.make(name_or_mesh) if isinstance(name_or_mesh, str) else name_or_mesh
        return self.layout.on_wall(self.room, mesh, **kw)

    def on(self, parent: int | None, mesh: ObjectMesh, surface: Surface | None = None, **kw) -> int | None:
        if parent is None:
            return None
        par = self.layout.placed[parent]
        surf = surface or par.mesh.surfaces[0]
        return self.layout.on_surface(parent, surf, mesh, **kw)


# --------------------------------------------------------------------------------------------------
# groups that recur across room kinds
# --------------------------------------------------------------------------------------------------
def _desk_clutter(r: _Room, desk_idx: int, n_items: int) -> None:
    """Cups, bottles, books, a desk lamp, a small plant or box at random spots on a desk or table."""
    choices = ("cup", "bottle", "book_flat", "lamp", "plant", "cup", "book_flat", "box")
    for _ in range(n_items):
        what = choices[int(r.rng.integers(len(choices)))]
        if what == "book_flat":
            mesh = r.make("book", thickness=r.u(0.17, 0.26), height=r.u(0.015, 0.04), depth=r.u(0.12, 0.19))
        elif what == "lamp":
            mesh = r.make("lamp", kind="desk")
        elif what == "plant":
            mesh = r.make("plant", tall=False)
        elif what == "box":
            mesh = r.make("box", size=(r.u(0.12, 0.25), r.u(0.1, 0.2), r.u(0.06, 0.15)))
        else:
            mesh = r.make(what)
        r.on(desk_idx, mesh, yaw_rel=r.u(-0.6, 0.6))


def _workstation(r: _Room) -> int | None:
    """Desk against a wall with an office chair, one or two monitors, a keyboard and clutter."""
    desk = r.wall("desk")
    if desk is None:
        return None
    r.layout.beside(desk, r.make("chair", style="office"), "front", gap=r.u(0.05, 0.25), jitter=0.3,
                    along=r.u(-0.2, 0.2))
    n_mon = 2 if r.chance(0.25) else 1
    xs = (0.5,) if n_mon == 1 else (0.3, 0.7)
    mon = None
    for fx in xs:
        mon = r.on(desk, r.make("monitor"), fx=fx + r.u(-0.05, 0.05), fy=r.u(0.8, 1.0), tries=1) or mon
    r.on(desk, r.make("keyboard"), fx=r.u(0.4, 0.6), fy=r.u(0.05, 0.3), yaw_rel=r.u(-0.1, 0.1))
    _desk_clutter(r, desk, int(r.rng.integers(1, 5)))
    return desk


def _bookshelf(r: _Room) -> int | None:
    """Shelf against a wall, its compartments filled with rows of books, the odd stack, box or plant."""
    shelf = r.wall("shelf")
    if shelf is None:
        return None
    for surf in r.layout.placed[shelf].mesh.surfaces:
        _fill_compartment(r, shelf, surf)
    return shelf


def _fill_compartment(r: _Room, shelf: int, surf: Surface) -> None:
    """Books standing side by side along a compartment, with gaps; sometimes a lying stack or a box."""
    depth = surf.y1 - surf.y0
    if r.chance(0.12):
        size = (r.u(0.15, 0.35), min(depth - 0.03, r.u(0.15, 0.3)), min(surf.clear - 0.03, r.u(0.1, 0.25)))
        r.on(shelf, r.make("box", size=size), surf)
        return
    fill = r.u(0.45, 0.95)
    x = surf.x0 + 0.005 + (r.u(0.0, 0.15) if r.chance(0.3) else 0.0)
    x_end = surf.x0 + fill * (surf.x1 - surf.x0)
    width = surf.x1 - surf.x0
    par = r.layout.placed[shelf]
    h_max = surf.clear - 0.015
    if h_max < 0.12:
        return
    while x < x_end:
        t = r.u(0.015, 0.05)
        if x + t > surf.x1 - 0.005:
            break
        mesh = r.make("book", thickness=t, height=r.u(min(0.17, h_max * 0.7), min(0.3, h_max)),
                      depth=r.u(min(0.13, depth - 0.02), depth - 0.01))
        lo, _ = rotated_bounds(mesh, 0.0)
        local = np.array([x - lo[0], surf.y0 + 0.003 - lo[1], surf.z])
        r.layout.try_pose(mesh, par.yaw, par.R @ local + par.t, par.room, "surface", parent=shelf, surface=surf)
        x += t + (r.u(0.04, 0.15) if r.chance(0.08) else r.u(0.0, 0.004))
    if x_end < surf.x1 - 0.3 and r.chance(0.4) and width > 0.5:
        mesh = r.make("plant", tall=False) if r.chance(0.5) else r.make("cup")
        r.on(shelf, mesh, surf, fx=r.u(0.8, 1.0), fy=r.u(0.2, 0.8))


def _dining_set(r: _Room, table_size: tuple[float, float] | None = None, coffee_items: int = 3) -> int | None:
    """Table free-standing near the room centre with chairs on its sides and things on top."""
    w, d = table_size or (r.u(1.0, 1.6), r.u(0.75, 0.9))
    mesh = r.make("table", w=w, d=d)
    room = r.layout.rooms[r.room]
    centre = 0.5 * (room.lo[:2] + room.hi[:2])
    idx = None
    for _ in range(30):
        xy = centre + r.rng.uniform(-0.25, 0.25, 2) * room.size[:2] * 0.5
        idx = r.layout.on_floor(r.room, mesh, yaw=float(r.rng.choice([0.0, np.pi / 2])), xy=xy)
        if idx is not None:
            break
    if idx is None:
        return None
    style = "dining" if r.chance(0.7) else "office"
    for side, span in (("front", w), ("back", w), ("left", d), ("right", d)):
        n = 2 if span > 1.25 else 1
        if side in ("left", "right") and r.chance(0.5):
            continue
        for k in range(n):
            along = 0.0 if n == 1 else (k - 0.5) * span * 0.5
            r.layout.beside(idx, r.make("chair", style=style), side, gap=r.u(0.02, 0.2), along=along, jitter=0.15)
    _desk_clutter(r, idx, coffee_items)
    return idx


def _wall_decor(r: _Room, n_pictures: int) -> None:
    """Pictures at eye height on free wall space."""
    H = r.layout.rooms[r.room].height
    for _ in range(n_pictures):
        mesh = r.make("picture")
        h = mesh.bounds()[1][2]
        z = float(np.clip(r.u(1.45, 1.65) - h / 2, 0.9, H - h - 0.15))
        r.wall(mesh, z=z)


def _floor_extras(r: _Room, plants: int, boxes: int, person_p: float, floor_lamp_p: float) -> None:
    """Tall plants and boxes along the walls, maybe a floor lamp, maybe a person standing about."""
    for _ in range(plants):
        r.wall(r.make("plant", tall=True), s_frac=(0.0, 0.15) if r.chance(0.5) else (0.85, 1.0))
    for _ in range(boxes):
        r.wall("box")
    if r.chance(floor_lamp_p):
        r.wall(r.make("lamp", kind="floor"), s_frac=(0.0, 0.2) if r.chance(0.5) else (0.8, 1.0))
    if r.chance(person_p):
        r.layout.on_floor(r.room, r.make("person"), border=0.6)


# --------------------------------------------------------------------------------------------------
# recipes
# --------------------------------------------------------------------------------------------------
def _office(r: _Room) -> None:
    for _ in range(r.n({"small": (1, 2), "medium": (2, 3), "large": (3, 5)})):
        _workstation(r)
    for _ in range(r.n({"small": (1, 1), "medium": (1, 2), "large": (2, 3)})):
        _bookshelf(r)
    for _ in range(r.n({"small": (0, 1), "medium": (1, 2), "large": (1, 3)})):
        tall = r.chance(0.5)
        cab = r.wall(r.make("cabinet", h=r.u(1.6, 2.0) if tall else r.u(0.7, 1.1), d=r.u(0.4, 0.5)))
        if cab is not None and not tall:
            _desk_clutter(r, cab, int(r.rng.integers(0, 3)))
    if r.size != "small" and r.chance(0.7):
        r.wall("whiteboard", z=r.u(0.85, 1.0))
    if r.size != "small" and r.chance(0.6 if r.size == "medium" else 0.9):
        big = r.size == "large"
        _dining_set(r, (r.u(1.4, 2.2) if big else r.u(1.2, 1.6), r.u(0.8, 1.0)),
                    coffee_items=int(r.rng.integers(1, 4)))
    _wall_decor(r, r.n({"small": (1, 2), "medium": (1, 3), "large": (2, 4)}))
    _floor_extras(r, plants=r.n({"small": (0, 1), "medium": (1, 2), "large": (1, 3)}),
                  boxes=r.n({"small": (0, 1), "medium": (0, 2), "large": (1, 3)}), person_p=0.5, floor_lamp_p=0.2)


def _kitchen(r: _Room) -> None:
    runs = r.n({"small": (1, 1), "medium": (1, 2), "large": (2, 2)})
    walls = r.rng.permutation(4)
    sink_done = False
    for i in range(runs):
        wall = int(walls[i])
        length = r.layout.rooms[r.room].walls[wall].length
        cw = min(length - 0.3, r.u(1.5, 3.0))
        counter = r.wall(r.make("counter", w=cw), wall=wall, s_frac=(0.0, 0.1) if r.chance(0.5) else (0.9, 1.0))
        if counter is None:
            continue
        if not sink_done:
            sink_done = r.on(counter, r.make("sink"), fx=r.u(0.35, 0.65), fy=0.5) is not None
        for _ in range(int(r.rng.integers(2, 5))):
            r.on(counter, r.make(("bottle", "cup", "bottle", "box")[int(r.rng.integers(4))]), fy=r.u(0.4, 1.0))
        wi, s = r.layout.wall_of[counter]
        upper = r.make("cabinet", w=cw, d=0.35, h=0.7, plinth=False, doors=max(1, round(cw / 0.5)))
        r.layout.on_wall(r.room, upper, wall=wi, s=s, z=1.45)
    r.wall("refrigerator")
    _dining_set(r, (r.u(0.9, 1.4), r.u(0.7, 0.9)), coffee_items=int(r.rng.integers(1, 4)))
    if r.chance(0.4):
        _bookshelf(r)
    if r.chance(0.5):
        r.wall(r.make("cabinet", h=r.u(0.8, 1.0), d=0.45))
    _wall_decor(r, r.n({"small": (0, 1), "medium": (1, 2), "large": (1, 3)}))
    _floor_extras(r, plants=r.n({"small": (0, 1), "medium": (0, 1), "large": (1, 2)}),
                  boxes=r.n({"small": (0, 1), "medium": (0, 1), "large": (0, 2)}), person_p=0.4, floor_lamp_p=0.0)


def _living_room(r: _Room) -> None:
    sofa = r.wall(r.make("sofa"), s_frac=(0.25, 0.75))
    if sofa is not None:
        seat = r.layout.placed[sofa].mesh.surfaces[0]
        n_p = int(r.rng.integers(1, 4))
        for fx in (0.0, 1.0, 0.5)[:n_p]:
            r.on(sofa, r.make("pillow"), seat, fx=fx, fy=1.0, yaw_rel=r.u(-0.15, 0.15))
        table = r.make("table", w=r.u(0.9, 1.2), d=r.u(0.5, 0.65), h=r.u(0.4, 0.46))
        ct = r.layout.beside(sofa, table, "front", gap=r.u(0.35, 0.5), yaw_rel=0.0)
        if ct is not None:
            _desk_clutter(r, ct, int(r.rng.integers(1, 4)))
            arm = meshes.sofa(r.rng, seats=1, class_name="chair")
            r.layout.beside(ct, arm, "left" if r.chance(0.5) else "right", gap=r.u(0.3, 0.5), jitter=0.2)
        wi, _ = r.layout.wall_of[sofa]
        stand = r.wall(r.make("cabinet", w=r.u(1.2, 1.7), d=r.u(0.4, 0.5), h=r.u(0.45, 0.55), doors=2, drawers=1),
                       wall=(wi + 2) % 4, s_frac=(0.3, 0.7))
        if stand is not None:
            r.on(stand, r.make("monitor", tv=True), fx=r.u(0.4, 0.6), fy=r.u(0.4, 0.6))
    for _ in range(r.n({"small": (0, 1), "medium": (1, 2), "large": (1, 3)})):
        _bookshelf(r)
    _wall_decor(r, r.n({"small": (1, 2), "medium": (1, 3), "large": (2, 4)}))
    _floor_extras(r, plants=r.n({"small": (0, 1), "medium": (1, 2), "large": (1, 3)}),
                  boxes=r.n({"small": (0, 1), "medium": (0, 1), "large": (0, 2)}), person_p=0.4, floor_lamp_p=0.7)


def _bedroom(r: _Room) -> None:
    bed = r.wall(r.make("bed", w=float(r.rng.choice([0.95, 1.45, 1.65])) if r.size != "small" else 0.95),
                 s_frac=(0.2, 0.8))
    if bed is not None:
        par = r.layout.placed[bed]
        surf = par.mesh.surfaces[0]
        wide = surf.x1 - surf.x0 > 1.0
        for fx in ((0.0, 1.0) if wide else (0.5,)):
            r.on(bed, r.make("pillow", lying=True, w=r.u(0.5, 0.65) if wide else r.u(0.5, 0.7)), surf, fx=fx, fy=1.0)
        blo, bhi = rotated_bounds(par.mesh, 0.0)
        for side in ("left", "right"):
            ns = r.make("cabinet", w=r.u(0.4, 0.5), d=r.u(0.35, 0.42), h=r.u(0.5, 0.6), doors=0, drawers=2,
                        class_name="nightstand")
            nlo, nhi = rotated_bounds(ns, 0.0)
            along = (bhi[1] - 0.5 * (blo[1] + bhi[1])) - 0.5 * (nhi[1] - nlo[1])
            idx = r.layout.beside(bed, ns, side, gap=r.u(0.02, 0.08), along=along, yaw_rel=0.0)
            if idx is not None:
                r.on(idx, r.make("lamp", kind="desk"), fx=0.5, fy=r.u(0.5, 1.0))
                _desk_clutter(r, idx, int(r.rng.integers(0, 2)))
    r.wall(r.make("cabinet", h=r.u(1.8, 2.1), d=r.u(0.55, 0.62), w=r.u(0.9, 1.4)))
    if r.size != "small" or r.chance(0.4):
        _workstation(r)
    if r.chance(0.6):
        _bookshelf(r)
    _wall_decor(r, r.n({"small": (1, 2), "medium": (1, 3), "large": (2, 3)}))
    _floor_extras(r, plants=r.n({"small": (0, 1), "medium": (0, 1), "large": (1, 2)}),
                  boxes=r.n({"small": (0, 1), "medium": (0, 2), "large": (1, 2)}), person_p=0.3, floor_lamp_p=0.3)


RECIPES: dict[str, Callable[[_Room], None]] = {
    "office": _office, "kitchen": _kitchen, "living_room": _living_room, "bedroom": _bedroom,
}


def furnish(layout: Layout, room: int, kind: str, size: str) -> None:
    """Place the furniture and small objects of a ``kind`` room (after its doors, windows and lights)."""
    RECIPES[kind](_Room(layout, room, size))
