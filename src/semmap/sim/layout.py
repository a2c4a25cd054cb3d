"""Room geometry and collision-free object placement (against walls, on the floor, on surfaces, beside others).

Every placed object is checked against all others with world-space axis-aligned boxes (objects touching is
fine, overlapping is not); the only exception is a child resting on its parent (a book in a shelf compartment,
a pillow on a sofa seat), which the parent's :class:`~semmap.sim.meshes.Surface` keeps clear by construction.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from semmap.sim.meshes import ObjectMesh, Surface
from semmap.types import rot_z

#: Two boxes closer than this are "touching", not overlapping (metres).
TOUCH_TOLERANCE = 1e-6
#: Thickness of the wall between two rooms (metres).
WALL_THICKNESS = 0.12

Rect = tuple[float, float, float, float]


@dataclass(frozen=True)
class Wall:
    """A wall seen from inside its room: floor-level start point, direction along it, inward normal (2-D)."""

    origin: np.ndarray
    along: np.ndarray
    normal: np.ndarray
    length: float

    def point(self, s: float) -> np.ndarray:
        return self.origin + s * self.along


@dataclass
class RoomSpec:
    """One box-shaped room: interior bounds, walls (south, east, north, west) and the shell areas to cut out."""

    name: str
    kind: str
    lo: np.ndarray  # (3,) interior minimum (floor at z = 0)
    hi: np.ndarray  # (3,) interior maximum (ceiling height)
    walls: list[Wall] = field(init=False)
    wall_holes: list[list[Rect]] = field(init=False)  # per wall: (s0, s1, z0, z1)
    floor_holes: list[Rect] = field(default_factory=list)  # (x0, x1, y0, y1)
    lights: list[np.ndarray] = field(default_factory=list)

    def __post_init__(self) -> None:
        (x0, y0), (x1, y1) = self.lo[:2], self.hi[:2]
        corners = [(x0, y0), (x1, y0), (x1, y1), (x0, y1)]
        normals = [(0.0, 1.0), (-1.0, 0.0), (0.0, -1.0), (1.0, 0.0)]
        self.walls = []
        for i in range(4):
            o = np.array(corners[i], float)
            e = np.array(corners[(i + 1) % 4], float)
            L = float(np.linalg.norm(e - o))
            self.walls.append(Wall(o, (e - o) / L, np.array(normals[i]), L))
        self.wall_holes = [[] for _ in range(4)]

    @property
    def size(self) -> np.ndarray:
        return self.hi - self.lo

    @property
    def height(self) -> float:
        return float(self.hi[2])


@dataclass
class Placed:
    """An object (or an invisible keep-out box when ``mesh`` is None) with its pose and world bounds."""

    mesh: ObjectMesh | None
    R: np.ndarray
    t: np.ndarray
    lo: np.ndarray
    hi: np.ndarray
    room: int
    mount: str  # "floor", "wall", "surface", "ceiling", "through" (door between rooms), "keepout"
    parent: int | None = None
    surface: Surface | None = None

    @property
    def yaw(self) -> float:
        return float(np.arctan2(self.R[1, 0], self.R[0, 0]))


def yaw_facing(normal: np.ndarray) -> float:
    """Yaw that turns an object's front (-y) towards the 2-D direction ``normal``."""
    return float(np.arctan2(normal[0], -normal[1]))


def rotated_bounds(mesh: ObjectMesh, yaw: float) -> tuple[np.ndarray, np.ndarray]:
    """Bounds of ``mesh`` rotated by ``yaw`` about z (object frame, no translation)."""
    V = np.concatenate([p.vertices for p in mesh.parts]) @ rot_z(yaw).T
    return V.min(0), V.max(0)


class Layout:
    """Rooms plus the objects placed so far; every ``place_*`` method returns the new index or None."""

    def __init__(self, rng: np.random.Generator) -> None:
        self.rng = rng
        self.rooms: list[RoomSpec] = []
        self.placed: list[Placed] = []
        #: object index -> (wall index, position along the wall) for objects placed with :meth:`on_wall`
        self.wall_of: dict[int, tuple[int, float]] = {}

    # ------------------------------------------------------------------ checks
    def is_free(self, lo: np.ndarray, hi: np.ndarray, room: int | None, ignore: tuple[int, ...] = ()) -> bool:
        """True when the box [lo, hi] lies inside ``room`` and overlaps no placed box (except ``ignore``)."""
        tol = TOUCH_TOLERANCE
        if room is not None:
            r = self.rooms[room]
            if np.any(lo < r.lo - tol) or np.any(hi > r.hi + tol):
                return False
        for j, p in enumerate(self.placed):
            if j in ignore:
                continue
            if np.all(lo < p.hi - tol) and np.all(hi > p.lo + tol):
                return False
        return True

    def _commit(self, mesh: ObjectMesh | None, R: np.ndarray, t: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                room: int, mount: str, parent: int | None = None, surface: Surface | None = None) -> int:
        self.placed.append(Placed(mesh, R, t, lo, hi, room, mount, parent, surface))
        return len(self.placed) - 1

    @staticmethod
    def world_bounds(mesh: ObjectMesh, R: np.ndarray, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        V = np.concatenate([p.vertices for p in mesh.parts]) @ R.T + t
        return V.min(0), V.max(0)

    def try_pose(self, mesh: ObjectMesh, yaw: float, t, room: int, mount: str, *, parent: int | None = None,
                 surface: Surface | None = None, check_room: bool = True) -> int | None:
        """Place ``mesh`` at (yaw, t) if that collides with nothing; returns the index or None."""
        R = rot_z(yaw)
        t = np.asarray(t, float)
        lo, hi = self.world_bounds(mesh, R, t)
        ignore = (parent,) if parent is not None else ()
        if not self.is_free(lo, hi, room if check_room else None, ignore):
            return None
        return self._commit(mesh, R, t, lo, hi, room, mount, parent, surface)

    def keepout(self, room: int, lo, hi) -> int:
        """Reserve a box nothing else may overlap (door swing, passage)."""
        return self._commit(None, np.eye(3), np.zeros(3), np.asarray(lo, float), np.asarray(hi, float), room,
                            "keepout")

    # ------------------------------------------------------------------ placement strategies
    def on_wall(self, room: int, mesh: ObjectMesh, *, wall: int | None = None, s: float | None = None,
                z: float = 0.0, tries: int = 30, margin: float = 0.03,
                s_frac: tuple[float, float] = (0.0, 1.0)) -> int | None:
        """Put ``mesh`` with its back (largest local y) against a wall, bottom at height ``z``.

        ``s`` is the position of the object's local x = 0 along the wall; random (within ``s_frac`` of the
        feasible range) when None. The wall is random when ``wall`` is None.
        """
        r = self.rooms[room]
        lo, hi = mesh.bounds()
        for _ in range(tries if s is None or wall is None else 1):
            wi = int(self.rng.integers(4)) if wall is None else wall
            w = r.walls[wi]
            s_min, s_max = margin + hi[0], w.length - margin + lo[0]
            if s_max < s_min:
                continue
            if s is None:
                a, b = s_min + (s_max - s_min) * s_frac[0], s_min + (s_max - s_min) * s_frac[1]
                si = float(self.rng.uniform(a, b))
            else:
                si = float(s)
                if not s_min - 1e-9 <= si <= s_max + 1e-9:
                    return None
            p = w.point(si) + hi[1] * w.normal
            idx = self.try_pose(mesh, yaw_facing(w.normal), (p[0], p[1], z), room, "wall" if z > 0 else "floor")
            if idx is not None:
                self.wall_of[idx] = (wi, si)
                return idx
        return None

    def on_floor(self, room: int, mesh: ObjectMesh, *, yaw: float | None = None, xy=None, tries: int = 40,
                 border: float = 0.3) -> int | None:
        """Put ``mesh`` free-standing on the floor at ``xy`` (random when None) with ``yaw`` (random: any)."""
        r = self.rooms[room]
        for _ in range(tries if xy is None else 1):
            y_ = float(self.rng.uniform(-np.pi, np.pi)) if yaw is None else yaw
            p = self.rng.uniform(r.lo[:2] + border, r.hi[:2] - border) if xy is None else np.asarray(xy, float)
            idx = self.try_pose(mesh, y_, (p[0], p[1], 0.0), room, "floor")
            if idx is not None:
                return idx
        return None

    def on_surface(self, parent: int, surface: Surface, mesh: ObjectMesh, *, yaw_rel: float = 0.0,
                   fx: float | None = None, fy: float | None = None, tries: int = 25,
                   margin: float = 0.01) -> int | None:
        """Rest ``mesh`` on ``surface`` of the placed object ``parent``; fx, fy in [0, 1] pick the spot."""
        par = self.placed[parent]
        lo, hi = rotated_bounds(mesh, yaw_rel)
        if hi[2] - lo[2] > surface.clear - 0.005:
            return None
        x_min, x_max = surface.x0 + margin - lo[0], surface.x1 - margin - hi[0]
        y_min, y_max = surface.y0 + margin - lo[1], surface.y1 - margin - hi[1]
        if x_max < x_min or y_max < y_min:
            return None
        for _ in range(tries if fx is None or fy is None else 1):
            ax = float(self.rng.random()) if fx is None else fx
            ay = float(self.rng.random()) if fy is None else fy
            local = np.array([x_min + ax * (x_max - x_min), y_min + ay * (y_max - y_min), surface.z - lo[2]])
            t = par.R @ local + par.t
            idx = self.try_pose(mesh, par.yaw + yaw_rel, t, par.room, "surface", parent=parent, surface=surface)
            if idx is not None:
                return idx
        return None

    def beside(self, parent: int, mesh: ObjectMesh, side: str, *, along: float = 0.0, gap: float = 0.05,
               yaw_rel: float | None = None, jitter: float = 0.0) -> int | None:
        """Stand ``mesh`` on the floor next to ``parent`` on ``side`` (front, back, left, right of the parent).

        The new object faces the parent unless ``yaw_rel`` is given; ``along`` shifts it along that side.
        """
        par = self.placed[parent]
        plo, phi = rotated_bounds(par.mesh, 0.0)
        facing = {"front": np.pi, "back": 0.0, "left": -np.pi / 2, "right": np.pi / 2}
        yr = facing[side] if yaw_rel is None else yaw_rel
        yr += float(self.rng.uniform(-jitter, jitter)) if jitter else 0.0
        lo, hi = rotated_bounds(mesh, yr)
        cx, cy = 0.5 * (plo[0] + phi[0]), 0.5 * (plo[1] + phi[1])
        if side == "front":
            local = (cx + along - 0.5 * (lo[0] + hi[0]), plo[1] - gap - hi[1])
        elif side == "back":
            local = (cx + along - 0.5 * (lo[0] + hi[0]), phi[1] + gap - lo[1])
        elif side == "left":
            local = (plo[0] - gap - hi[0], cy + along - 0.5 * (lo[1] + hi[1]))
        else:
            local = (phi[0] + gap - lo[0], cy + along - 0.5 * (lo[1] + hi[1]))
        t = par.R @ np.array([local[0], local[1], 0.0]) + par.t
        t[2] = 0.0
        return self.try_pose(mesh, par.yaw + yr, t, par.room, "floor")



def subtract_rects(outer: Rect, holes: list[Rect]) -> list[Rect]:
    """Cover ``outer`` minus the union of ``holes`` with disjoint rectangles (grid cut, rows merged)."""
    x0, x1, y0, y1 = outer
    clipped = [(max(a, x0), min(b, x1), max(c, y0), min(d, y1)) for a, b, c, d in holes]
    clipped = [h for h in clipped if h[1] - h[0] > 1e-9 and h[3] - h[2] > 1e-9]
    xs = sorted({x0, x1, *[v for h in clipped for v in h[:2]]})
    ys = sorted({y0, y1, *[v for h in clipped for v in h[2:]]})
    out: list[Rect] = []
    for j in range(len(ys) - 1):
        cy = 0.5 * (ys[j] + ys[j + 1])
        run_start = None
        for i in range(len(xs) - 1):
            cx = 0.5 * (xs[i] + xs[i + 1])
            solid = not any(a < cx < b and c < cy < d for a, b, c, d in clipped)
            if solid and run_start is None:
                run_start = xs[i]
            if not solid and run_start is not None:
                out.append((run_start, xs[i], ys[j], ys[j + 1]))
                run_start = None
        if run_start is not None:
            out.append((run_start, xs[-1], ys[j], ys[j + 1]))
    return out
