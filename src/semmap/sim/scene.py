"""Procedural indoor scenes: a furnished room (optionally a second one behind a door) as one triangle mesh
with per-triangle class, instance and material, plus the object list and the generator parameters.

World frame: z up, floor at z = 0, metres; the main room spans x in [0, W], y in [0, D].
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from semmap.errors import SimulationError
from semmap.labels import INDOOR_LABELS, STUFF_CLASSES
from semmap.sim import meshes
from semmap.sim.furnish import furnish
from semmap.sim.layout import WALL_THICKNESS, Layout, RoomSpec, subtract_rects, yaw_facing
from semmap.sim.materials import PAINTS, Material, jitter_color, pick
from semmap.sim.primitives import face_uvs
from semmap.sim.symmetric import mirror_half
from semmap.types import LabelSet

KINDS: tuple[str, ...] = ("office", "kitchen", "living_room", "bedroom")
SIZES: tuple[str, ...] = ("small", "medium", "large")
#: Room footprint ranges (W min, W max, D min, D max) in metres per size.
ROOM_DIMS: dict[str, tuple[float, float, float, float]] = {
    "small": (3.4, 4.2, 3.0, 3.6),
    "medium": (4.8, 6.0, 4.0, 5.0),
    "large": (6.8, 8.4, 5.5, 6.8),
}
#: Probability of a second room when ``second_room`` is None.
SECOND_ROOM_P: dict[str, float] = {"small": 0.0, "medium": 0.3, "large": 0.6}
CEILING_RANGE = (2.5, 2.8)
DOOR_KEEPOUT_DEPTH = 0.9
#: Faces closer than this to a contact plane (floor, wall, ceiling) count as lying on it.
PLANE_TOLERANCE = 1e-7
#: Version of the generator; bump when the same seed starts giving a different scene.
GENERATOR_VERSION = 1


@dataclass(frozen=True)
class SceneObject:
    """One object instance: ids, class, area-weighted surface centroid and world bounding box (metres)."""

    instance_id: int
    class_id: int
    class_name: str
    centroid: np.ndarray
    bbox_min: np.ndarray
    bbox_max: np.ndarray

    def to_dict(self) -> dict:
        return {"id": self.instance_id, "class": self.class_name, "class_id": self.class_id,
                "centroid": [round(float(v), 6) for v in self.centroid],
                "bbox_min": [round(float(v), 6) for v in self.bbox_min],
                "bbox_max": [round(float(v), 6) for v in self.bbox_max]}


@dataclass(frozen=True)
class Room:
    """Interior box of one room (floor at z = 0) and its furnishing kind."""

    name: str
    kind: str
    bounds_min: np.ndarray
    bounds_max: np.ndarray


@dataclass
class Scene:
    """Merged scene mesh and its ground truth.

    ``vertices`` (V, 3) float32, ``triangles`` (T, 3) int32, ``uvs`` (V, 2) float32 (texture coordinates,
    see :class:`~semmap.sim.materials.Material`), per triangle ``tri_class`` uint16, ``tri_instance`` int32
    (0 for wall/floor/ceiling) and ``tri_material`` int32 indexing ``materials``. ``openings`` are the
    passages between rooms as (min, max) boxes; ``hulls`` the convex parts (instance id, world vertices)
    the objects are made of, for interpenetration checks.
    """

    vertices: np.ndarray
    triangles: np.ndarray
    uvs: np.ndarray
    tri_class: np.ndarray
    tri_instance: np.ndarray
    tri_material: np.ndarray
    materials: list[Material]
    objects: list[SceneObject]
    rooms: list[Room]
    openings: list[tuple[np.ndarray, np.ndarray]]
    lights: np.ndarray
    params: dict
    hulls: list[tuple[int, np.ndarray]] = field(repr=False, default_factory=list)
    supports: dict[int, int] = field(default_factory=dict)  # child instance id -> parent instance id
    label_set: LabelSet = INDOOR_LABELS

    @property
    def bounds_min(self) -> np.ndarray:
        return np.min([r.bounds_min for r in self.rooms], axis=0)

    @property
    def bounds_max(self) -> np.ndarray:
        return np.max([r.bounds_max for r in self.rooms], axis=0)

    @property
    def n_triangles(self) -> int:
        return len(self.triangles)

    def object(self, instance_id: int) -> SceneObject:
        for o in self.objects:
            if o.instance_id == instance_id:
                return o
        raise SimulationError(f"scene has no object with instance id {instance_id}")

    def inside_rooms(self, points: np.ndarray, margin: float = 0.0) -> np.ndarray:
        """Mask of (N, 3) points inside some room (shrunk by ``margin``) or inside a passage between rooms."""
        p = np.atleast_2d(points)
        inside = np.zeros(len(p), bool)
        boxes = [(r.bounds_min, r.bounds_max) for r in self.rooms]
        for lo, hi in boxes:
            inside |= np.all((p >= lo + margin) & (p <= hi - margin), axis=1)
        for lo, hi in self.openings:  # a passage reaches ``margin`` into the rooms on both sides
            axis = int(np.argmin((hi - lo)[:2]))
            ext = np.zeros(3)
            ext[axis] = margin
            inside |= np.all((p >= lo - ext) & (p <= hi + ext), axis=1)
        return inside


def generate_scene(seed: int, kind: str = "office", size: str = "medium",
                   second_room: bool | None = None, *, symmetric: bool = False) -> Scene:
    """Furnished ``kind`` room of ``size`` from ``seed`` (deterministic), with a second room behind a door
    when ``second_room`` is True (None: decided by the seed, more likely for larger sizes).  ``symmetric``: one
    room whose geometry maps onto itself under a 180° turn and whose halves differ only in their classes
    (:mod:`semmap.sim.symmetric`)."""
    if kind not in KINDS:
        raise SimulationError(f"unknown scene kind {kind!r}; choose one of {', '.join(KINDS)}")
    if size not in SIZES:
        raise SimulationError(f"unknown scene size {size!r}; choose one of {', '.join(SIZES)}")
    if not isinstance(seed, (int, np.integer)) or seed < 0:
        raise SimulationError(f"scene seed must be a non-negative integer, got {seed!r}")
    if symmetric and second_room:
        raise SimulationError("a symmetric scene has one room (second_room must not be True)")
    rng = np.random.default_rng([int(seed), KINDS.index(kind), SIZES.index(size), 7919])
    layout = Layout(rng)

    W, D = _room_dims(rng, size)
    H = float(rng.uniform(*CEILING_RANGE))
    layout.rooms.append(RoomSpec("main", kind, np.zeros(3), np.array([W, D, H])))
    has_second = bool(rng.random() < SECOND_ROOM_P[size]) if second_room is None else bool(second_room)
    has_second = has_second and not symmetric
    params: dict = {"generator_version": GENERATOR_VERSION, "seed": int(seed), "kind": kind, "size": size,
                    "second_room": has_second}
    openings: list[tuple[np.ndarray, np.ndarray]] = []
    door_walls = {0: [1] if has_second else []}
    if has_second:
        kind2 = str(rng.choice([k for k in KINDS if k != kind]))
        W2, D2 = _room_dims(rng, "small")
        D2 = min(D2, D)
        y0 = float(rng.uniform(0.0, D - D2))
        x0 = W + WALL_THICKNESS
        layout.rooms.append(RoomSpec("second", kind2, np.array([x0, y0, 0.0]), np.array([x0 + W2, y0 + D2, H])))
        openings.append(_connect(layout, rng))
        door_walls[1] = [3]
        params["second_kind"] = kind2

    for i in range(len(layout.rooms)):
        _add_fixtures(layout, i, rng, exterior_door=(i == 0), taken_walls=door_walls.get(i, []))
    for i, room in enumerate(layout.rooms):
        furnish(layout, i, room.kind, size if i == 0 else "small")
    if symmetric:
        mirror_half(layout, 0)
        params["symmetric"] = True
    params["rooms"] = [{"name": r.name, "kind": r.kind, "min": [round(float(v), 6) for v in r.lo],
                        "max": [round(float(v), 6) for v in r.hi]} for r in layout.rooms]
    return _assemble(layout, rng, openings, params)


# --------------------------------------------------------------------------------------------------
# shell: rooms, doors, windows, lights
# --------------------------------------------------------------------------------------------------
def _room_dims(rng: np.random.Generator, size: str) -> tuple[float, float]:
    w0, w1, d0, d1 = ROOM_DIMS[size]
    return float(rng.uniform(w0, w1)), float(rng.uniform(d0, d1))


def _connect(layout: Layout, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Doorway through the wall between room 0 (its east wall) and room 1; returns the passage box."""
    main, second = layout.rooms
    w, h = float(rng.uniform(0.85, 0.95)), float(rng.uniform(2.0, 2.1))
    y_lo = max(main.lo[1], second.lo[1]) + w / 2 + 0.35
    y_hi = min(main.hi[1], second.hi[1]) - w / 2 - 0.35
    if y_hi < y_lo:
        raise SimulationError("rooms overlap too little for a door between them")
    yc = float(rng.uniform(y_lo, y_hi))
    wall = main.walls[1]
    s = yc - main.lo[1]
    mesh = meshes.doorway(rng, w, h, WALL_THICKNESS, hinge=int(rng.choice([-1, 1])))
    p = wall.point(s)
    idx = layout.try_pose(mesh, yaw_facing(wall.normal), (p[0], p[1], 0.0), 0, "through", check_room=False)
    if idx is None:  # pragma: no cover - the doorway is the first object placed
        raise SimulationError("could not place the doorway between the rooms")
    main.wall_holes[1].append((s - w / 2, s + w / 2, 0.0, h))
    s2 = second.hi[1] - yc
    second.wall_holes[3].append((s2 - w / 2, s2 + w / 2, 0.0, h))
    for r, wi, si in ((0, 1, s), (1, 3, s2)):
        _door_keepout(layout, r, wi, si, w)
    x_lo, x_hi = main.hi[0], second.lo[0]
    return (np.array([x_lo - 0.01, yc - w / 2 + 0.03, 0.0]), np.array([x_hi + 0.01, yc + w / 2 - 0.03, h - 0.03]))


def _door_keepout(layout: Layout, room: int, wall: int, s: float, w: float) -> None:
    """Keep the floor in front of a door free so it can open and people (and cameras) can pass."""
    wl = layout.rooms[room].walls[wall]
    a = wl.point(s - w / 2 - 0.1)
    b = wl.point(s + w / 2 + 0.1) + DOOR_KEEPOUT_DEPTH * wl.normal
    lo = np.minimum(a, b)
    hi = np.maximum(a, b)
    layout.keepout(room, (lo[0], lo[1], 0.0), (hi[0], hi[1], 2.1))


def _add_fixtures(layout: Layout, room: int, rng: np.random.Generator, *, exterior_door: bool,
                  taken_walls: list[int]) -> None:
    """Exterior door, window(s) with curtains, and ceiling lights of one room."""
    r = layout.rooms[room]
    free_walls = [i for i in range(4) if i not in taken_walls]
    door_wall = None
    if exterior_door:
        door_wall = int(rng.choice(free_walls))
        mesh = meshes.door(rng)
        idx = layout.on_wall(room, mesh, wall=door_wall, s_frac=(0.05, 0.95))
        if idx is not None:
            _, s = layout.wall_of[idx]
            _door_keepout(layout, room, door_wall, s, mesh.bounds()[1][0] * 2)
    window_walls = [i for i in free_walls if i != door_wall] or free_walls
    n_windows = 2 if r.size[0] * r.size[1] > 30 else 1
    for _ in range(n_windows):
        wall = int(rng.choice(window_walls))
        sill = float(rng.uniform(0.8, 1.0))
        h_max = r.height - 0.3 - sill
        mesh = meshes.window(rng, w=float(rng.uniform(0.9, min(1.8, r.walls[wall].length * 0.4))),
                             h=float(rng.uniform(min(1.0, h_max), h_max)))
        idx = layout.on_wall(room, mesh, wall=wall, z=sill)
        if idx is None or rng.random() > {"living_room": 0.9, "bedroom": 0.9}.get(r.kind, 0.25):
            continue
        _, s = layout.wall_of[idx]
        half = mesh.bounds()[1][0] + 0.06
        for side in (-1, 1):
            cur = meshes.curtain(rng, h=r.height - 0.06)
            cw = cur.bounds()[1][0]
            layout.on_wall(room, cur, wall=wall, s=s + side * (half + cw + 0.01))
    n_lights = 1 if r.size[0] * r.size[1] < 16 else 2
    long_axis = int(np.argmax(r.size[:2]))
    for k in range(n_lights):
        c = 0.5 * (r.lo + r.hi)
        c[long_axis] = r.lo[long_axis] + r.size[long_axis] * (k + 0.5) / n_lights
        mesh = meshes.ceiling_light(rng, panel=(r.kind == "office"))
        top = mesh.bounds()[1][2]
        layout.try_pose(mesh, 0.0, (c[0], c[1], r.height - top), room, "ceiling")
        r.lights.append(np.array([c[0], c[1], r.height - 0.25]))


# --------------------------------------------------------------------------------------------------
# assembly
# --------------------------------------------------------------------------------------------------
class _MeshBuffer:
    """Accumulates triangles with their attributes and deduplicated materials."""

    def __init__(self) -> None:
        self.V: list[np.ndarray] = []
        self.F: list[np.ndarray] = []
        self.UV: list[np.ndarray] = []
        self.cls: list[np.ndarray] = []
        self.inst: list[np.ndarray] = []
        self.mat: list[np.ndarray] = []
        self.offsets: list[int] = []
        self.n_vertices = 0
        self.materials: list[Material] = []
        self._mat_index: dict[Material, int] = {}

    def material(self, m: Material) -> int:
        if m not in self._mat_index:
            self._mat_index[m] = len(self.materials)
            self.materials.append(m)
        return self._mat_index[m]

    def add(self, V: np.ndarray, F: np.ndarray, UV: np.ndarray, class_id: int, instance: int, mat: int) -> None:
        if len(F) == 0:
            return
        self.V.append(V)
        self.offsets.append(self.n_vertices)
        self.F.append(F + self.n_vertices)
        self.UV.append(UV)
        self.cls.append(np.full(len(F), class_id, np.uint16))
        self.inst.append(np.full(len(F), instance, np.int32))
        self.mat.append(np.full(len(F), mat, np.int32))
        self.n_vertices += len(V)

    def quad(self, corners: np.ndarray, normal: np.ndarray, class_id: int, mat: int) -> None:
        """Planar quad (4 corners, counter-clockwise seen from ``normal``) of a shell surface."""
        uv = face_uvs(corners, normal, np.zeros(3), fit=False)
        self.add(corners, np.array([[0, 1, 2], [0, 2, 3]], np.int32), uv.astype(np.float32), class_id, 0, mat)


def _assemble(layout: Layout, rng: np.random.Generator, openings, params: dict) -> Scene:
    buf = _MeshBuffer()
    objects: list[SceneObject] = []
    hulls: list[tuple[int, np.ndarray]] = []
    supports: dict[int, int] = {}
    instance_of: dict[int, int] = {}
    next_id = 1
    for idx, p in enumerate(layout.placed):
        if p.mesh is None:
            continue
        instance_of[idx] = next_id
        next_id += 1
    for idx, p in enumerate(layout.placed):
        if p.mesh is None:
            continue
        inst = instance_of[idx]
        cid = INDOOR_LABELS.id_of(p.mesh.class_name)
        back_wall = _wall_behind(layout, idx)
        drops = _contact_planes(layout, idx, back_wall is not None)
        start = len(buf.F)
        for part in p.mesh.parts:
            keep = _keep_faces(part.vertices, part.triangles, drops)
            world = part.vertices @ p.R.T + p.t
            hulls.append((inst, world))
            buf.add(world, part.triangles[keep], part.uvs, cid, inst,
                    buf.material(p.mesh.materials[part.material]))
        objects.append(_scene_object(inst, cid, p.mesh.class_name, buf, start, p))
        if p.parent is not None and layout.placed[p.parent].mesh is not None:
            supports[inst] = instance_of[p.parent]
        _cut_shell(layout, idx, back_wall)
    _add_shell(layout, rng, buf)

    vertices = np.concatenate(buf.V).astype(np.float32)
    return Scene(
        vertices=vertices,
        triangles=np.concatenate(buf.F).astype(np.int32),
        uvs=np.concatenate(buf.UV).astype(np.float32),
        tri_class=np.concatenate(buf.cls),
        tri_instance=np.concatenate(buf.inst),
        tri_material=np.concatenate(buf.mat),
        materials=buf.materials,
        objects=objects,
        rooms=[Room(r.name, r.kind, r.lo.copy(), r.hi.copy()) for r in layout.rooms],
        openings=openings,
        lights=np.array([light for r in layout.rooms for light in r.lights], np.float64).reshape(-1, 3),
        params=params,
        hulls=hulls,
        supports=supports,
    )


def _scene_object(inst: int, cid: int, name: str, buf: _MeshBuffer, start: int, p) -> SceneObject:
    """Object record with the area-weighted centroid of its (kept) triangles."""
    areas, cents = [], []
    for k in range(start, len(buf.F)):
        T = buf.V[k][buf.F[k] - buf.offsets[k]]
        areas.append(0.5 * np.linalg.norm(np.cross(T[:, 1] - T[:, 0], T[:, 2] - T[:, 0]), axis=1))
        cents.append(T.mean(axis=1))
    a = np.concatenate(areas) if areas else np.zeros(0)
    c = np.concatenate(cents) if cents else np.zeros((0, 3))
    centroid = (a[:, None] * c).sum(0) / a.sum() if a.sum() > 0 else 0.5 * (p.lo + p.hi)
    return SceneObject(inst, cid, name, centroid, p.lo.copy(), p.hi.copy())


def _wall_behind(layout: Layout, idx: int) -> tuple[int, int, float] | None:
    """(room, wall, s of local x = 0) when the object's back (largest local y) lies on a wall of its room."""
    p = layout.placed[idx]
    if p.mount in ("through", "ceiling", "surface"):
        return None
    room = layout.rooms[p.room]
    back_y = p.mesh.bounds()[1][1]
    normal2 = -p.R[:2, 1]  # world direction of the object's front (-y)
    for wi, w in enumerate(room.walls):
        if not np.allclose(normal2, w.normal, atol=1e-9):
            continue
        back_point = p.t[:2] - back_y * w.normal
        dist = float(np.dot(back_point - w.origin, w.normal))
        if abs(dist) < PLANE_TOLERANCE * 10:
            return p.room, wi, float(np.dot(p.t[:2] - w.origin, w.along))
    return None


def _contact_planes(layout: Layout, idx: int, wall_backed: bool) -> list[tuple[int, float, float]]:
    """Planes (axis, value, outward sign) in the object frame whose faces touch the floor/wall/support."""
    p = layout.placed[idx]
    hi = p.mesh.bounds()[1]
    planes = []
    if p.mount in ("floor", "surface") or (p.mount == "wall" and p.t[2] <= PLANE_TOLERANCE):
        planes.append((2, 0.0, -1.0))
    if p.mount == "ceiling":
        planes.append((2, float(hi[2]), 1.0))
    if wall_backed:
        planes.append((1, float(hi[1]), 1.0))
    return planes


def _keep_faces(V: np.ndarray, F: np.ndarray, planes: list[tuple[int, float, float]]) -> np.ndarray:
    """Mask of triangles that do not lie on a contact plane facing into it (hidden, never seen)."""
    keep = np.ones(len(F), bool)
    if not planes:
        return keep
    n = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    for axis, value, sign in planes:
        on = np.all(np.abs(V[F][:, :, axis] - value) < PLANE_TOLERANCE, axis=1)
        keep &= ~(on & (n[:, axis] * sign > 0))
    return keep


def _cut_shell(layout: Layout, idx: int, back_wall: tuple[int, int, float] | None) -> None:
    """Record the wall and floor rectangles the object hides, to be left out of the shell mesh."""
    p = layout.placed[idx]
    mesh = p.mesh
    if back_wall is not None and mesh.wall_cover is not None:
        room, wi, s = back_wall
        x0, x1, z0, z1 = mesh.wall_cover
        layout.rooms[room].wall_holes[wi].append((s - x1, s - x0, p.t[2] + z0, p.t[2] + z1))
    yaw_quarter = abs(np.sin(2 * p.yaw)) < 1e-9
    if mesh.floor_cover is not None and p.mount in ("floor", "wall") and p.t[2] <= PLANE_TOLERANCE \
            and yaw_quarter:
        x0, x1, y0, y1 = mesh.floor_cover
        corners = np.array([[x0, y0, 0], [x1, y0, 0], [x1, y1, 0], [x0, y1, 0]], float) @ p.R.T + p.t
        lo, hi = corners.min(0), corners.max(0)
        layout.rooms[p.room].floor_holes.append((lo[0], hi[0], lo[1], hi[1]))


def _shell_materials(rng: np.random.Generator, kind: str) -> tuple[Material, Material, Material]:
    """(floor, wall, ceiling) materials for a room kind."""
    seed = int(rng.integers(2**31))
    if kind == "kitchen" or (kind == "office" and rng.random() < 0.4):
        tile = float(rng.choice([0.3, 0.4, 0.5, 0.6]))
        color = jitter_color(rng, pick(rng, ((200, 195, 185), (170, 170, 175), (120, 110, 100), (215, 210, 200))))
        floor = Material("tiles", color, (0, 0, 0), 2 * tile, seed, 512)
    elif kind == "office" or rng.random() < 0.3:
        floor = Material("carpet", jitter_color(rng, pick(rng, ((90, 95, 110), (120, 110, 100), (70, 80, 70)))),
                         (0, 0, 0), 1.0, seed, 256)
    else:
        floor = Material("planks", jitter_color(rng, pick(rng, ((170, 125, 80), (140, 100, 65), (200, 160, 115)))),
                         (0, 0, 0), float(rng.uniform(0.7, 1.0)), seed, 512)
    wall = Material("paint", jitter_color(rng, pick(rng, PAINTS), 0.05), (0, 0, 0), 1.0, seed + 1, 256)
    if kind == "office":
        ceiling = Material("ceiling_tiles", (225, 225, 220), (0, 0, 0), 1.2, seed + 2, 256)
    else:
        ceiling = Material("paint", (235, 235, 230), (0, 0, 0), 1.0, seed + 2, 256)
    return floor, wall, ceiling


def _add_shell(layout: Layout, rng: np.random.Generator, buf: _MeshBuffer) -> None:
    """Floor, ceiling and wall quads of every room, minus the holes objects and doorways cut into them."""
    cls = {name: INDOOR_LABELS.id_of(name) for name in STUFF_CLASSES}
    for r in layout.rooms:
        floor_m, wall_m, ceil_m = (buf.material(m) for m in _shell_materials(rng, r.kind))
        (x0, y0, _), (x1, y1, H) = r.lo, r.hi
        for a, b, c, d in subtract_rects((x0, x1, y0, y1), r.floor_holes):
            buf.quad(np.array([[a, c, 0], [b, c, 0], [b, d, 0], [a, d, 0]], float), np.array([0.0, 0, 1]),
                     cls["floor"], floor_m)
        buf.quad(np.array([[x0, y0, H], [x0, y1, H], [x1, y1, H], [x1, y0, H]], float), np.array([0.0, 0, -1]),
                 cls["ceiling"], ceil_m)
        for wi, w in enumerate(r.walls):
            n3 = np.array([w.normal[0], w.normal[1], 0.0])
            for s0, s1, z0, z1 in subtract_rects((0.0, w.length, 0.0, H), r.wall_holes[wi]):
                p0, p1 = w.point(s0), w.point(s1)
                corners = np.array([[p0[0], p0[1], z0], [p0[0], p0[1], z1], [p1[0], p1[1], z1], [p1[0], p1[1], z0]])
                buf.quad(corners, n3, cls["wall"], wall_m)
