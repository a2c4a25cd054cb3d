"""The same scene a while later: some objects moved, removed or added (a copy of one placed elsewhere), so maps of
two recordings can be compared against the true changes (``semmap simulate --changes N``, ``semmap diff``).

Only free-standing floor objects change (not doors, windows, wall fixtures, objects that carry or stand on others):
what a person tidying a room moves. A new place is a spot on the floor of the same room whose footprint keeps
``CLEARANCE`` from every other object, the walls and the doorways. Deterministic in ``seed``.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from semmap.errors import SimulationError
from semmap.sim.scene import Scene, SceneObject

#: Gap kept between a moved or added object's footprint and everything else (metres).
CLEARANCE = 0.15
#: Classes that are part of the building, never moved.
FIXED_CLASSES = frozenset({"wall", "floor", "ceiling", "door", "window", "picture", "curtain", "whiteboard"})
#: Classes that move by themselves: a map leaves them out (dynamic classes), so a diff cannot see them change.
SELF_MOVING = frozenset({"person"})
KINDS = ("move", "remove", "add")


def _movable(scene: Scene) -> list[SceneObject]:
    carried = set(scene.supports.values()) | set(scene.supports)
    return [o for o in scene.objects if o.class_name not in FIXED_CLASSES | SELF_MOVING and o.instance_id not in carried
            and o.bbox_min[2] < 0.05 and np.all(o.bbox_max[:2] - o.bbox_min[:2] < 1.6)]


def _room_of(scene: Scene, o: SceneObject):
    c = (o.bbox_min + o.bbox_max) / 2
    return next((r for r in scene.rooms if np.all(c[:2] >= r.bounds_min[:2]) and np.all(c[:2] <= r.bounds_max[:2])),
                None)


def _free_spot(scene: Scene, o: SceneObject, others: list[SceneObject], rng: np.random.Generator) -> np.ndarray | None:
    """An xy offset that puts ``o``'s footprint on free floor of its room, or None after 300 tries."""
    room = _room_of(scene, o)
    if room is None:
        return None
    size = o.bbox_max[:2] - o.bbox_min[:2]
    lo, hi = room.bounds_min[:2] + CLEARANCE, room.bounds_max[:2] - CLEARANCE - size
    if np.any(hi <= lo):
        return None
    blocked = [(b.bbox_min[:2] - CLEARANCE, b.bbox_max[:2] + CLEARANCE) for b in others]
    blocked += [(a[:2] - 0.6, b[:2] + 0.6) for a, b in scene.openings]  # keep doorways passable
    for _ in range(300):
        corner = rng.uniform(lo, hi)
        if all(np.any(corner + size <= b_lo) or np.any(corner >= b_hi) for b_lo, b_hi in blocked):
            return np.array([*(corner - o.bbox_min[:2]), 0.0])
    return None


def _moved(obj: SceneObject, offset: np.ndarray, instance_id: int | None = None) -> SceneObject:
    return replace(obj, instance_id=obj.instance_id if instance_id is None else instance_id,
                   centroid=obj.centroid + offset, bbox_min=obj.bbox_min + offset, bbox_max=obj.bbox_max + offset)


def _apply(scene: Scene, kind: str, o: SceneObject, offset: np.ndarray | None, new_id: int) -> Scene:
    """The scene with one change made to its mesh, hulls and object list."""
    mine = scene.tri_instance == o.instance_id
    if kind == "remove":
        keep = ~mine
        return replace(scene, triangles=scene.triangles[keep], tri_class=scene.tri_class[keep],
                       tri_instance=scene.tri_instance[keep], tri_material=scene.tri_material[keep],
                       objects=[b for b in scene.objects if b.instance_id != o.instance_id],
                       hulls=[h for h in scene.hulls if h[0] != o.instance_id])
    verts = np.unique(scene.triangles[mine])
    if kind == "move":
        vertices = scene.vertices.copy()
        vertices[verts] += offset.astype(np.float32)
        objects = [_moved(b, offset) if b.instance_id == o.instance_id else b for b in scene.objects]
        hulls = [(i, v + offset if i == o.instance_id else v) for i, v in scene.hulls]
        return replace(scene, vertices=vertices, objects=objects, hulls=hulls)
    remap = np.full(len(scene.vertices), -1, np.int64)  # add: a copy of the object's triangles, placed anew
    remap[verts] = len(scene.vertices) + np.arange(len(verts))
    tris = remap[scene.triangles[mine]].astype(np.int32)
    return replace(scene, vertices=np.concatenate([scene.vertices, scene.vertices[verts] + offset.astype(np.float32)]),
                   uvs=np.concatenate([scene.uvs, scene.uvs[verts]]),
                   triangles=np.concatenate([scene.triangles, tris]),
                   tri_class=np.concatenate([scene.tri_class, scene.tri_class[mine]]),
                   tri_instance=np.concatenate([scene.tri_instance, np.full(len(tris), new_id, np.int32)]),
                   tri_material=np.concatenate([scene.tri_material, scene.tri_material[mine]]),
                   objects=[*scene.objects, _moved(o, offset, new_id)],
                   hulls=[*scene.hulls, *[(new_id, v + offset) for i, v in scene.hulls if i == o.instance_id]])


def change_scene(scene: Scene, changes: int, seed: int = 0) -> tuple[Scene, list[dict]]:
    """``scene`` with ``changes`` objects moved, removed or added (in turn), and the record of each change."""
    if not isinstance(changes, (int, np.integer)) or not 0 <= changes <= 50:
        raise SimulationError(f"changes must be a whole number from 0 to 50, got {changes!r}")
    rng = np.random.default_rng([int(seed), 104729])
    record: list[dict] = []
    for i in range(int(changes)):
        kind = KINDS[i % len(KINDS)]
        candidates = [o for o in _movable(scene) if o.instance_id not in {r["id"] for r in record}]
        if not candidates:
            raise SimulationError(f"the scene has only {i} objects that can change; ask for fewer --changes")
        o = candidates[int(rng.integers(len(candidates)))]
        offset = None
        if kind != "remove":
            offset = _free_spot(scene, o, [b for b in scene.objects if b.instance_id != o.instance_id or kind == "add"],
                                rng)
            if offset is None:
                kind, offset = "remove", None  # no free floor left: the change becomes a removal
        new_id = max(b.instance_id for b in scene.objects) + 1
        scene = _apply(scene, kind, o, offset, new_id)
        entry = {"change": kind, "id": o.instance_id, "class": o.class_name,
                 "from": [round(float(v), 4) for v in o.centroid]}
        if kind != "remove":
            entry["to"] = [round(float(v), 4) for v in o.centroid + offset]
        if kind == "add":
            entry["new_id"] = new_id
        record.append(entry)
    scene = replace(scene, params={**scene.params, "changes": int(changes), "changes_seed": int(seed)})
    return scene, record
