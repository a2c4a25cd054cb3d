"""People walking through a scene (``semmap simulate --people N``), to test that maps keep them out.

Each walker is a person mesh (:func:`semmap.sim.meshes.person`) that walks to and fro along a path over free
floor (a shortest path through the clearance map between two far-apart spots), facing where it goes, labelled
``person`` with an instance id of its own. It keeps ``CAMERA_GAP`` from the camera and from the other walkers in
every frame. The static scene is left as it was (its ground truth, ``objects.json``, its triangle count): the
walkers are added to a copy of its mesh that only the renderer sees (:func:`add_people`), and their vertices are
moved before each frame is rendered (:meth:`Walker.place`). Deterministic in ``seed``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from semmap.errors import SimulationError
from semmap.labels import INDOOR_LABELS
from semmap.sim import meshes
from semmap.sim.freespace import FreeSpace
from semmap.sim.scene import Scene

#: Walking speed (m/s).
WALK_SPEED = 0.9
#: Clearance of a walker's path to walls and furniture (m): half a person's width and a margin.
PATH_CLEARANCE = 0.35
#: Horizontal distance a walker keeps from the camera and from other walkers in every frame (m).
CAMERA_GAP = 0.7
#: Shortest path a walker takes (m).
MIN_PATH = 1.5
#: ... and the gap it accepts when no tried path keeps CAMERA_GAP (m).
MIN_GAP = 0.5
ATTEMPTS = 60
_STREAM = 0x9E0


@dataclass(frozen=True)
class Walker:
    """One walking person: its mesh in its own frame (front -y, feet at z = 0), where its vertices and triangles
    sit in the rendered mesh, and the path (P, 2) it walks to and fro from ``phase`` metres on at t = 0."""

    instance_id: int
    vertices: np.ndarray  # (V, 3) float64, the person's own frame
    first_vertex: int
    triangles: slice  # its triangles in the rendered mesh
    path: np.ndarray  # (P, 2) float64 xy polyline
    phase: float
    speed: float = WALK_SPEED

    def position(self, t: float | np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Where the walker stands (xy, (..., 2)) and the direction it faces (yaw, radians) at time ``t`` (s)."""
        cum = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(self.path, axis=0), axis=1))])
        length = cum[-1]
        s = np.mod(self.phase + self.speed * np.asarray(t, np.float64), 2 * length)
        back = s > length
        s = np.where(back, 2 * length - s, s)  # to and fro
        xy = np.stack([np.interp(s, cum, self.path[:, k]) for k in range(2)], -1)
        ahead = np.clip(s + np.where(back, -0.25, 0.25), 0.0, length)
        behind = np.clip(s - np.where(back, -0.25, 0.25), 0.0, length)
        d = np.stack([np.interp(ahead, cum, self.path[:, k]) - np.interp(behind, cum, self.path[:, k])
                      for k in range(2)], -1)
        return xy, np.arctan2(d[..., 1], d[..., 0])

    def vertices_at(self, t: float) -> np.ndarray:
        """The walker's vertices (V, 3) in the world at time ``t``: its front (-y) turned to where it walks."""
        xy, yaw = self.position(t)
        a = float(yaw) + np.pi / 2  # local -y -> (cos yaw, sin yaw)
        c, s = np.cos(a), np.sin(a)
        R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        return self.vertices @ R.T + np.array([xy[0], xy[1], 0.0])


def add_people(scene: Scene, n: int, seed: int, cameras: np.ndarray, fps: float) -> tuple[Scene, list[Walker]]:
    """The scene to render (``scene`` plus ``n`` person meshes) and the walkers that move them, for the camera
    positions ``cameras`` (F, 3) seen at ``fps`` frames per second; SimulationError when no free path keeps the
    walkers ``CAMERA_GAP`` from the camera and each other."""
    if not isinstance(n, (int, np.integer)) or not 0 <= n <= 8:
        raise SimulationError(f"people must be a whole number from 0 to 8, got {n!r}")
    if n == 0:
        return scene, []
    rng = np.random.default_rng([int(seed), _STREAM])
    space = FreeSpace(scene)
    cells = space.free_cells(PATH_CLEARANCE, within=space.largest_region(PATH_CLEARANCE, room=0))
    if len(cells) < 2:
        raise SimulationError("the scene has no free floor for a walking person")
    times = np.arange(len(cameras)) / fps
    walkers: list[Walker] = []
    out = scene
    for _ in range(int(n)):
        path, phase = _walk(space, cells, rng, times, cameras[:, :2], [w.position(times)[0] for w in walkers])
        out, walker = _append_person(out, meshes.person(rng), path, phase)
        walkers.append(walker)
    return out, walkers


def _walk(space: FreeSpace, cells: np.ndarray, rng: np.random.Generator, times: np.ndarray, cameras: np.ndarray,
          others: list[np.ndarray]) -> tuple[np.ndarray, float]:
    """A path and start phase whose walk stays ``CAMERA_GAP`` from the cameras and the other walkers; the best
    of ``ATTEMPTS`` tries (the first that keeps the gap)."""
    best, best_gap = None, -1.0
    for _ in range(ATTEMPTS):
        a, b = cells[rng.integers(len(cells))], cells[rng.integers(len(cells))]
        if np.linalg.norm(a - b) < MIN_PATH:
            continue
        try:
            path = space.shortest_path(a, b, PATH_CLEARANCE)
        except SimulationError:
            continue
        length = float(np.linalg.norm(np.diff(path, axis=0), axis=1).sum())
        phase = float(rng.uniform(0.0, 2 * length))
        probe = Walker(0, np.zeros((0, 3)), 0, slice(0, 0), path, phase)
        xy = probe.position(times)[0]
        gap = min(float(np.linalg.norm(xy - c, axis=-1).min()) for c in (cameras, *others))
        if gap > best_gap:
            best, best_gap = (path, phase), gap
        if gap >= CAMERA_GAP:
            break
    if best is None or best_gap < MIN_GAP:
        raise SimulationError(f"no path for a walking person keeps {CAMERA_GAP} m from the camera in every frame "
                              "(fewer --people, or another trajectory)")
    return best


def _append_person(scene: Scene, mesh: meshes.ObjectMesh, path: np.ndarray, phase: float) -> tuple[Scene, Walker]:
    """``scene`` with the person's triangles appended (class ``person``, a new instance id, its own materials)."""
    inst = max([o.instance_id for o in scene.objects] + [int(scene.tri_instance.max(initial=0))]) + 1
    v0, t0, m0 = len(scene.vertices), len(scene.triangles), len(scene.materials)
    verts, tris, uvs, mats = [], [], [], []
    offset = 0
    for part in mesh.parts:
        verts.append(part.vertices)
        tris.append(part.triangles + v0 + offset)
        uvs.append(part.uvs)
        mats.append(np.full(len(part.triangles), m0 + part.material, np.int32))
        offset += len(part.vertices)
    own = np.concatenate(verts).astype(np.float64)
    n_tri = sum(len(t) for t in tris)
    walker = Walker(inst, own, v0, slice(t0, t0 + n_tri), np.asarray(path, np.float64), phase)
    out = replace(scene, vertices=np.concatenate([scene.vertices, walker.vertices_at(0.0).astype(np.float32)]),
                  triangles=np.concatenate([scene.triangles, *tris]).astype(np.int32),
                  uvs=np.concatenate([scene.uvs, *uvs]).astype(np.float32),
                  tri_class=np.concatenate([scene.tri_class, np.full(n_tri, INDOOR_LABELS.id_of("person"),
                                                                     np.uint16)]),
                  tri_instance=np.concatenate([scene.tri_instance, np.full(n_tri, inst, np.int32)]),
                  tri_material=np.concatenate([scene.tri_material, *mats]),
                  materials=[*scene.materials, *mesh.materials])
    return out, walker


def person_cells(scene: Scene, walkers: list[Walker], times: np.ndarray, resolution: float) -> np.ndarray:
    """Packed keys of every voxel a walker's surface passed through at ``times`` (seconds), its triangles sampled
    finer than ``resolution``; ``scene`` is the rendered one (:func:`add_people`). Take the static scene's voxels
    away and what is left is where only a person ever was."""
    from semmap.keys import coords_to_keys, pack_keys

    keys = [np.zeros(0, np.int64)]
    for w in walkers:
        tris = scene.triangles[w.triangles] - w.first_vertex
        edge = max(float(np.linalg.norm(w.vertices[tris[:, i]] - w.vertices[tris[:, (i + 1) % 3]], axis=1).max())
                   for i in range(3))
        n = max(1, int(np.ceil(2.0 * edge / resolution)))
        a, b = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
        keep = a + b <= n
        bary = np.stack([a[keep], b[keep], n - a[keep] - b[keep]], 1) / n  # (S, 3) barycentric samples
        for t in times:
            v = w.vertices_at(float(t))[tris]  # (T, 3 corners, 3)
            pts = np.einsum("sc,tcd->tsd", bary, v).reshape(-1, 3)
            keys.append(pack_keys(coords_to_keys(pts, resolution)))
    return np.unique(np.concatenate(keys))
