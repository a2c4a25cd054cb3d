"""Hand-held camera trajectories through a scene: desk scan, room loop, orbit around an object, walk-through.

Each kind builds a smooth path (shortest paths through a clearance map, Gaussian-smoothed, or analytic
sweeps), orients the camera (look-at targets or heading + pitch), adds small hand shake (a few sinusoids in
translation and rotation) and is then checked: inside the rooms, outside every object box, at 1.2-1.7 m, and
looking at something (the principal ray hits a surface within the sensor range for almost all frames).
A failed check retries with the next random stream; all randomness comes from ``seed``.
"""

from __future__ import annotations

from itertools import pairwise

import numpy as np
from scipy.ndimage import gaussian_filter1d

from semmap.errors import SimulationError
from semmap.sim.freespace import FreeSpace, part_boxes
from semmap.sim.hand_motion import MotionParams, handheld
from semmap.sim.render import center_depths, scene_raycaster
from semmap.sim.scene import Scene, SceneObject
from semmap.types import make_pose

TRAJECTORY_KINDS: tuple[str, ...] = ("desk", "loop", "orbit", "walk")
HEIGHT_RANGE = (1.2, 1.7)
#: Camera clearance from walls and furniture footprints along walking paths (metres).
WALK_CLEARANCE = 0.28
#: Camera keeps this distance from every object box (metres).
OBJECT_MARGIN = 0.08
#: ... and this distance from the walls of its room.
WALL_MARGIN = 0.15
#: Principal-ray depth must be in (MIN_VIEW, MAX_VIEW) metres for at least LOOK_FRACTION of the frames.
MIN_VIEW, MAX_VIEW = 0.4, 4.5
LOOK_FRACTION = 0.95
MAX_SPEED = 0.8  # m/s, walking and loop paths
MIN_WALK_SPEED = 0.35  # m/s: a walk-through adds waypoints until it keeps moving at least this fast
MAX_ATTEMPTS = 8
_STREAM = 0x7A1


def look_at(eye, target, roll: float = 0.0) -> np.ndarray:
    """``T_world_cam`` at ``eye`` looking at ``target`` with world z up (camera y down), rolled by ``roll`` rad."""
    eye = np.asarray(eye, float)
    f = np.asarray(target, float) - eye
    f /= np.linalg.norm(f)
    x = np.cross(f, [0.0, 0.0, 1.0])
    if np.linalg.norm(x) < 1e-9:
        raise SimulationError("look_at: viewing direction is vertical")
    x /= np.linalg.norm(x)
    y = np.cross(f, x)
    c, s = np.cos(roll), np.sin(roll)
    R = np.stack([c * x + s * y, -s * x + c * y, f], 1)
    return make_pose(R, eye)


def heading_pose(eye, yaw: float, pitch: float, roll: float = 0.0) -> np.ndarray:
    """``T_world_cam`` at ``eye`` looking along ``yaw`` (about z) and ``pitch`` (negative = down), radians."""
    f = np.array([np.cos(pitch) * np.cos(yaw), np.cos(pitch) * np.sin(yaw), np.sin(pitch)])
    return look_at(eye, np.asarray(eye, float) + f, roll)


def make_trajectory(scene: Scene, kind: str, n_frames: int, seed: int, fps: float = 30.0,
                    motion: MotionParams | None = None) -> np.ndarray:
    """(n_frames, 4, 4) ``T_world_cam`` poses of a ``kind`` trajectory (desk, loop, orbit, walk) at ``fps``;
    ``motion`` with ``hand=True`` (:mod:`semmap.sim.hand_motion`) carries the camera like a hand along the path
    instead of the builders' even pace and small shake (default: the smooth path)."""
    if kind not in TRAJECTORY_KINDS:
        raise SimulationError(f"unknown trajectory kind {kind!r}; choose one of {', '.join(TRAJECTORY_KINDS)}")
    if not isinstance(n_frames, (int, np.integer)) or n_frames <= 0:
        raise SimulationError(f"n_frames must be a positive integer, got {n_frames!r}")
    if not fps > 0:
        raise SimulationError(f"fps must be positive, got {fps}")
    space = FreeSpace(scene)
    checker = scene_raycaster(scene)
    t = np.arange(n_frames) / fps
    last = ""
    for attempt in range(MAX_ATTEMPTS):
        rng = np.random.default_rng([_STREAM, int(seed), TRAJECTORY_KINDS.index(kind), attempt])
        try:
            poses = _BUILDERS[kind](scene, space, rng, t, attempt)
        except SimulationError as exc:
            last = str(exc)
            continue
        if motion is not None and motion.hand:
            poses = handheld(poses, rng, motion, fps, checker, scene.tri_class)
        else:
            poses = _add_shake(poses, rng, t)
        problem = check_trajectory(scene, poses, checker)
        if problem is None:
            return poses
        last = problem
    raise SimulationError(f"could not build a valid {kind!r} trajectory in this scene: {last}")


def check_trajectory(scene: Scene, poses: np.ndarray, raycaster=None) -> str | None:
    """None when every pose is inside the rooms, away from every object part, at camera height, and (given an
    open3d ``raycaster``) looks at something in range for LOOK_FRACTION of the frames; else what is wrong."""
    p = poses[:, :3, 3]
    if not scene.inside_rooms(p, margin=WALL_MARGIN).all():
        return "camera leaves the rooms"
    lo, hi = HEIGHT_RANGE
    if p[:, 2].min() < lo - 0.02 or p[:, 2].max() > hi + 0.02:
        return "camera height out of range"
    lo, hi = part_boxes(scene)
    for k in range(len(p)):
        inside = np.all((p[k] > lo - OBJECT_MARGIN) & (p[k] < hi + OBJECT_MARGIN), axis=1)
        if inside.any():
            inst = scene.hulls[int(np.argmax(inside))][0]
            return f"camera inside object {inst} ({scene.object(inst).class_name})"
    if raycaster is not None:
        d = center_depths(raycaster, poses)
        ok = (d > MIN_VIEW) & (d < MAX_VIEW)
        if ok.mean() < LOOK_FRACTION:
            return f"camera looks at nothing in range in {100 * (1 - ok.mean()):.0f}% of the frames"
    return None


# --------------------------------------------------------------------------------------------------
# kinds
# --------------------------------------------------------------------------------------------------
def _loop(scene: Scene, space: FreeSpace, rng: np.random.Generator, t: np.ndarray, attempt: int) -> np.ndarray:
    """Closed loop around the main room's free centre, looking across the room; 1.25 laps (revisits)."""
    path = _closed_loop(space, rng, room=0)
    laps = 1.25
    length = _length(path, closed=True)
    duration = t[-1] + (t[1] - t[0] if len(t) > 1 else 1 / 30)
    speed = min(laps * length / duration, MAX_SPEED)
    s = (speed * t + 0.05 * speed * np.sin(2 * np.pi * t / 5.0)) % length
    pos = _along(path, s, closed=True)
    tangent = _along(path, (s + 0.3) % length, closed=True) - _along(path, (s - 0.3) % length, closed=True)
    centre = path.mean(0)
    radial = pos - centre
    radial /= np.maximum(np.linalg.norm(radial, axis=1, keepdims=True), 1e-9)
    tangent /= np.maximum(np.linalg.norm(tangent, axis=1, keepdims=True), 1e-9)
    look = -radial + 0.6 * tangent  # across the room, a little ahead: sees furniture, not blank walls
    yaw = np.unwrap(np.arctan2(look[:, 1], look[:, 0]))
    fps = 1.0 / (t[1] - t[0]) if len(t) > 1 else 30.0
    yaw = gaussian_filter1d(yaw, sigma=0.3 * fps, mode="nearest")
    pitch = np.radians(-18 - 3 * attempt + 5 * np.sin(2 * np.pi * t / 7.0 + rng.uniform(0, 2 * np.pi)))
    height = _height(rng, t)
    return _poses_from_heading(pos, height, yaw, pitch, _roll(rng, t))


def _walk(scene: Scene, space: FreeSpace, rng: np.random.Generator, t: np.ndarray, attempt: int) -> np.ndarray:
    """Walk from one end of the main room through the door into the second room (or across the room)."""
    region = space.largest_region(WALK_CLEARANCE, room=0)
    door = None
    if len(scene.rooms) > 1:
        door = 0.5 * (scene.openings[0][0][:2] + scene.openings[0][1][:2])
        through = space.largest_region(WALK_CLEARANCE, through=door)
        if (through & (space.room_id == 0)).any() and (through & (space.room_id == 1)).any():
            region = through
        else:
            door = None
    spots0 = space.free_cells(0.45, room=0, within=region)
    if len(spots0) == 0:
        raise SimulationError("no free floor space to walk in")
    if door is not None:
        spots1 = space.free_cells(0.45, room=1, within=region)
        if len(spots1) == 0:
            raise SimulationError("no free floor space in the second room")
        far = spots0[np.argsort(-np.linalg.norm(spots0 - door, axis=1), kind="stable")[:max(1, len(spots0) // 4)]]
        start = far[int(rng.integers(len(far)))]
        goal = spots1[int(rng.integers(len(spots1)))]
        waypoints = [start, goal]
    else:
        waypoints = [spots0[int(rng.integers(len(spots0)))]]
    duration = max(t[-1], 1e-9)
    path = _route(space, waypoints, closed=False) if len(waypoints) > 1 else np.array(waypoints)
    while _length(path, closed=False) < MIN_WALK_SPEED * duration and len(waypoints) < 12:
        # keep walking: on to a far point of the room we are not in (or of the same room when alone)
        pool = spots0 if door is None or len(waypoints) % 2 == 0 else spots1
        d = np.linalg.norm(pool - waypoints[-1], axis=1)
        cand = pool[d >= np.percentile(d, 60)]
        waypoints.append(cand[int(rng.integers(len(cand)))])
        path = _route(space, waypoints, closed=False)
    length = _length(path, closed=False)
    speed = min(length / duration, MAX_SPEED)
    s = np.clip(speed * t, 0.0, length)
    pos = _along(path, s, closed=False)
    ahead = _along(path, np.clip(s + 0.8, 0, length), closed=False) - _along(path, np.clip(s - 0.2, 0, length),
                                                                            closed=False)
    ahead /= np.maximum(np.linalg.norm(ahead, axis=1, keepdims=True), 1e-9)
    inward = np.array([_room_center(scene, p) for p in pos]) - pos
    inward /= np.maximum(np.linalg.norm(inward, axis=1, keepdims=True), 1e-9)
    ahead = ahead + 0.6 * inward  # turn towards the middle of the room rather than into walls
    yaw = np.unwrap(np.arctan2(ahead[:, 1], ahead[:, 0]))
    yaw = gaussian_filter1d(yaw, sigma=10.0, mode="nearest")
    yaw = yaw + np.radians(25) * np.sin(2 * np.pi * t / 6.0 + rng.uniform(0, 2 * np.pi))
    pitch = np.radians(-15 - 3 * attempt + 6 * np.sin(2 * np.pi * t / 5.0 + rng.uniform(0, 2 * np.pi)))
    return _poses_from_heading(pos, _height(rng, t), yaw, pitch, _roll(rng, t))


def _orbit(scene: Scene, space: FreeSpace, rng: np.random.Generator, t: np.ndarray, attempt: int) -> np.ndarray:
    """Circle (or sweep back and forth on the free arc) around a large object, looking at its centre."""
    candidates = [o for o in scene.objects if o.class_name in _ORBIT_CLASSES and _room_of(scene, o) == 0]
    best = None
    for o in candidates:
        half = 0.5 * np.linalg.norm((o.bbox_max - o.bbox_min)[:2])
        for r in (half + 0.7, half + 1.0, half + 1.4):
            if not 0.9 <= r <= 2.4:
                continue
            arc = _free_arc(space, o, r)
            if arc is None:
                continue
            score = arc[1] + 0.3 * half + 0.05 * rng.random()
            if best is None or score > best[0]:
                best = (score, o, r, arc)
    if best is None:
        raise SimulationError("no object with free space around it to orbit")
    _, obj, radius, (a0, span) = best
    centre = 0.5 * (obj.bbox_min + obj.bbox_max)
    duration = max(t[-1], 1e-9)
    if span >= np.radians(350):
        omega = min(2 * np.pi * 1.1 / duration, MAX_SPEED / radius)
        ang = a0 + omega * t
    else:
        amp = 0.45 * span
        period = max(8.0, 4 * amp * radius / (0.6 * MAX_SPEED))
        ang = a0 + 0.5 * span + amp * np.sin(2 * np.pi * t / period + rng.uniform(-0.5, 0.5))
    r = radius + 0.1 * np.sin(2 * np.pi * t / 9.0 + rng.uniform(0, 2 * np.pi))
    pos = centre[:2] + np.stack([r * np.cos(ang), r * np.sin(ang)], 1)
    height = _height(rng, t)
    target = np.array([centre[0], centre[1], min(obj.bbox_max[2], max(0.3, centre[2]))])
    wobble = 0.08 * np.stack([np.sin(2 * np.pi * t / 4.3), np.cos(2 * np.pi * t / 5.1), np.zeros_like(t)], 1)
    roll = _roll(rng, t)
    return np.stack([look_at((pos[i, 0], pos[i, 1], height[i]), target + wobble[i], roll[i])
                     for i in range(len(t))])


def _desk(scene: Scene, space: FreeSpace, rng: np.random.Generator, t: np.ndarray, attempt: int) -> np.ndarray:
    """TUM fr1_desk-like hand-held sweeps in front of a desk or table, looking down at its top."""
    order = {"desk": 0, "table": 1, "counter": 2, "nightstand": 3, "cabinet": 4, "bed": 5, "sofa": 6, "box": 7,
             "chair": 8}
    surfaces = sorted((o for o in scene.objects if o.class_name in order and o.bbox_max[2] < 1.2),
                      key=lambda o: (order[o.class_name], _room_of(scene, o), o.instance_id))
    if not surfaces:
        raise SimulationError("no desk or table to scan")
    obj = surfaces[min(attempt // 2, len(surfaces) - 1)] if attempt < 2 * len(surfaces) else \
        surfaces[int(rng.integers(len(surfaces)))]
    side = _open_side(scene, obj, rng)
    lo, hi = obj.bbox_min, obj.bbox_max
    axis, sign = side
    lat = 1 - axis  # lateral axis (0 = x, 1 = y)
    half_len = 0.5 * (hi[lat] - lo[lat])
    mid_lat = 0.5 * (hi[lat] + lo[lat])
    edge = hi[axis] if sign > 0 else lo[axis]
    ph = rng.uniform(0, 2 * np.pi, 4)
    sweep = max(0.05, half_len - 0.1)
    lateral = mid_lat + sweep * (0.7 * np.sin(2 * np.pi * t / 6.0 + ph[0]) + 0.3 * np.sin(2 * np.pi * t / 2.3 + ph[1]))
    dist = 0.55 + 0.2 * np.sin(2 * np.pi * t / 4.7 + ph[2])
    height = np.clip(max(hi[2] + 0.6, 1.32) + 0.1 * np.sin(2 * np.pi * t / 5.3 + ph[3]), *HEIGHT_RANGE)
    depth_in = 0.3 * (hi[axis] - lo[axis]) + 0.1 * np.sin(2 * np.pi * t / 3.1 + ph[1])
    target_lat = mid_lat + 0.8 * (lateral - mid_lat) + 0.1 * np.sin(2 * np.pi * t / 2.7 + ph[2])
    cam = np.zeros((len(t), 3))
    tgt = np.zeros((len(t), 3))
    cam[:, axis] = edge + sign * dist
    cam[:, lat] = lateral
    cam[:, 2] = height
    tgt[:, axis] = edge - sign * depth_in
    tgt[:, lat] = target_lat
    tgt[:, 2] = hi[2]
    roll = _roll(rng, t, amp_deg=4.0)
    return np.stack([look_at(cam[i], tgt[i], roll[i]) for i in range(len(t))])


_BUILDERS = {"loop": _loop, "walk": _walk, "orbit": _orbit, "desk": _desk}
_ORBIT_CLASSES = frozenset({"table", "desk", "sofa", "bed", "chair", "cabinet", "plant", "person", "counter",
                            "refrigerator", "box", "nightstand", "shelf"})


# --------------------------------------------------------------------------------------------------
# helpers
# --------------------------------------------------------------------------------------------------
def _room_of(scene: Scene, o: SceneObject) -> int:
    c = 0.5 * (o.bbox_min + o.bbox_max)
    for i, r in enumerate(scene.rooms):
        if np.all(c[:2] >= r.bounds_min[:2]) and np.all(c[:2] <= r.bounds_max[:2]):
            return i
    return -1


def _room_center(scene: Scene, p: np.ndarray) -> np.ndarray:
    """Centre (x, y) of the room containing the 2-D point ``p`` (the main room's when in none)."""
    for r in scene.rooms:
        if np.all(p >= r.bounds_min[:2]) and np.all(p <= r.bounds_max[:2]):
            return 0.5 * (r.bounds_min[:2] + r.bounds_max[:2])
    r = scene.rooms[0]
    return 0.5 * (r.bounds_min[:2] + r.bounds_max[:2])


def _height(rng: np.random.Generator, t: np.ndarray) -> np.ndarray:
    """Camera height wandering slowly inside HEIGHT_RANGE (hand-held at chest to eye level)."""
    lo, hi = HEIGHT_RANGE
    base = rng.uniform(lo + 0.1, hi - 0.1)
    h = base + 0.08 * np.sin(2 * np.pi * t / 6.5 + rng.uniform(0, 2 * np.pi)) \
        + 0.04 * np.sin(2 * np.pi * t / 2.9 + rng.uniform(0, 2 * np.pi))
    return np.clip(h, lo + 0.02, hi - 0.02)


def _roll(rng: np.random.Generator, t: np.ndarray, amp_deg: float = 2.0) -> np.ndarray:
    return np.radians(amp_deg) * np.sin(2 * np.pi * t / 5.7 + rng.uniform(0, 2 * np.pi))


def _poses_from_heading(pos: np.ndarray, height: np.ndarray, yaw: np.ndarray, pitch: np.ndarray,
                        roll: np.ndarray) -> np.ndarray:
    return np.stack([heading_pose((pos[i, 0], pos[i, 1], height[i]), yaw[i], pitch[i], roll[i])
                     for i in range(len(pos))])


def _add_shake(poses: np.ndarray, rng: np.random.Generator, t: np.ndarray) -> np.ndarray:
    """Hand tremor: a few sinusoids of 1-4 Hz, a few millimetres and a few tenths of a degree."""
    out = poses.copy()
    trans = np.zeros((len(t), 3))
    rot = np.zeros((len(t), 3))
    for _ in range(3):
        for arr, amp in ((trans, rng.uniform(0.001, 0.003, 3)), (rot, np.radians(rng.uniform(0.05, 0.3, 3)))):
            f = rng.uniform(1.0, 4.0, 3)
            ph = rng.uniform(0, 2 * np.pi, 3)
            arr += amp * np.sin(2 * np.pi * f * t[:, None] + ph)
    for i in range(len(t)):
        rx, ry, rz = rot[i]
        dR = _small_rotation(rx, ry, rz)
        out[i, :3, :3] = poses[i, :3, :3] @ dR
        out[i, :3, 3] = poses[i, :3, 3] + trans[i]
    return out


def _small_rotation(rx: float, ry: float, rz: float) -> np.ndarray:
    """Rotation matrix of the rotation vector (rx, ry, rz) (Rodrigues)."""
    v = np.array([rx, ry, rz])
    a = np.linalg.norm(v)
    if a < 1e-15:
        return np.eye(3)
    k = v / a
    Kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(a) * Kx + (1 - np.cos(a)) * Kx @ Kx


def _length(path: np.ndarray, closed: bool) -> float:
    seg = np.diff(np.vstack([path, path[:1]]) if closed else path, axis=0)
    return float(np.linalg.norm(seg, axis=1).sum())


def _along(path: np.ndarray, s: np.ndarray, closed: bool) -> np.ndarray:
    """Points at arc lengths ``s`` along a polyline (wrapping when closed)."""
    pts = np.vstack([path, path[:1]]) if closed else path
    cum = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))])
    return np.stack([np.interp(s, cum, pts[:, k]) for k in range(pts.shape[1])], 1)


def _resample(path: np.ndarray, step: float, closed: bool) -> np.ndarray:
    length = _length(path, closed)
    n = max(2, int(np.ceil(length / step)))
    s = np.linspace(0.0, length, n, endpoint=not closed)
    return _along(path, s, closed)


def _smooth(space: FreeSpace, path: np.ndarray, closed: bool) -> np.ndarray:
    """Gaussian-smoothed path, as smooth as the clearance allows."""
    pts = _resample(path, 0.05, closed)
    for sigma_m in (0.5, 0.35, 0.25, 0.15, 0.08):
        sm = gaussian_filter1d(pts, sigma=sigma_m / 0.05, axis=0, mode="wrap" if closed else "nearest")
        if (space.clearance_at(sm) >= WALK_CLEARANCE - 0.05).all():
            return sm
    return pts


def _route(space: FreeSpace, waypoints: list[np.ndarray], closed: bool) -> np.ndarray:
    """Smoothed chain of shortest paths through the waypoints."""
    legs = []
    stops = [*waypoints, waypoints[0]] if closed else list(waypoints)
    for a, b in pairwise(stops):
        legs.append(space.shortest_path(a, b, WALK_CLEARANCE))
    path = np.vstack([leg if k == 0 else leg[1:] for k, leg in enumerate(legs)])
    if closed:
        path = path[:-1]
    return _smooth(space, path, closed)


def _closed_loop(space: FreeSpace, rng: np.random.Generator, room: int) -> np.ndarray:
    """A loop around the room's free middle: best-clearance points on 10 rays from the centre, joined."""
    cells = space.free_cells(WALK_CLEARANCE + 0.1, room=room, within=space.largest_region(WALK_CLEARANCE, room))
    if len(cells) < 10:
        raise SimulationError("too little free floor for a loop")
    centre = cells.mean(0)
    offsets = cells - centre
    ang = np.arctan2(offsets[:, 1], offsets[:, 0])
    rad = np.linalg.norm(offsets, axis=1)
    clear = space.clearance_at(cells)
    n_rays = 10
    start = rng.uniform(0, 2 * np.pi)
    waypoints = []
    for k in range(n_rays):
        a = start + 2 * np.pi * k / n_rays
        near = np.abs(np.angle(np.exp(1j * (ang - a)))) < np.pi / n_rays
        if not near.any():
            continue
        r_pref = 0.5 * rad[near].max()
        score = np.minimum(clear[near], 0.8) - 0.5 * np.abs(rad[near] - r_pref)
        waypoints.append(cells[near][int(np.argmax(score))])
    if len(waypoints) < 4:
        raise SimulationError("free floor too fragmented for a loop")
    return _route(space, waypoints, closed=True)


def _free_arc(space: FreeSpace, o: SceneObject, radius: float) -> tuple[float, float] | None:
    """(start angle, span) of the longest free arc of the circle of ``radius`` around object ``o``."""
    c = 0.5 * (o.bbox_min + o.bbox_max)[:2]
    ang = np.radians(np.arange(0, 360, 5.0))
    pts = c + radius * np.stack([np.cos(ang), np.sin(ang)], 1)
    ok = space.clearance_at(pts) >= WALK_CLEARANCE
    if ok.all():
        return 0.0, 2 * np.pi
    if not ok.any():
        return None
    first_bad = int(np.argmin(ok))
    rolled = np.roll(ok, -first_bad)
    best_len, best_start, run = 0, 0, 0
    for i, v in enumerate(rolled):
        run = run + 1 if v else 0
        if run > best_len:
            best_len, best_start = run, i - run + 1
    if best_len < 8:  # less than 40 degrees
        return None
    step = np.radians(5.0)
    return float(ang[(best_start + first_bad) % len(ang)]), float((best_len - 1) * step)


def _open_side(scene: Scene, o: SceneObject, rng: np.random.Generator) -> tuple[int, int]:
    """(axis, sign) of the side of ``o``'s box where a standing person can hold a camera over it: inside the
    room and clear of anything taller than a chair, weighted by the side's length."""
    c = 0.5 * (o.bbox_min + o.bbox_max)
    tall = [q for q in scene.objects if q.bbox_max[2] > HEIGHT_RANGE[0] - OBJECT_MARGIN - 0.02
            and q.bbox_min[2] < HEIGHT_RANGE[1] + 0.1]
    best, best_score = (1, -1), -1.0
    for axis in (0, 1):
        for sign in (-1, 1):
            lat = 1 - axis
            edge = o.bbox_max[axis] if sign > 0 else o.bbox_min[axis]
            span = o.bbox_max[lat] - o.bbox_min[lat]
            d, off = np.meshgrid(np.linspace(0.35, 0.75, 5), np.linspace(-0.4, 0.4, 5) * span)
            pts = np.zeros((d.size, 3))
            pts[:, axis] = edge + sign * d.ravel()
            pts[:, lat] = c[lat] + off.ravel()
            pts[:, 2] = HEIGHT_RANGE[0] + 0.1
            ok = scene.inside_rooms(pts, margin=WALL_MARGIN + 0.05)
            for q in tall:
                ok &= ~np.all((pts[:, :2] > q.bbox_min[:2] - 0.15) & (pts[:, :2] < q.bbox_max[:2] + 0.15), axis=1)
            score = float(ok.mean()) * span + 0.01 * rng.random()
            if score > best_score:
                best, best_score = (axis, sign), score
    return best
