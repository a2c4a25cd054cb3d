"""A scene graph of a mapped place: objects (class, centroid, box, points), rooms, and the relations between them
(object in room, object on object, objects near each other), written with spark-dsg in the format Hydra's tools
read (``scene_graph.json``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from semmap.errors import ConfigError
from semmap.products.rooms import RoomMap

#: Largest gap (m) between the bottom of an object's box and the top of the one below it for "on".
ON_GAP = 0.08
#: Centroid distance (m) under which two objects of one room are "near".
NEAR = 1.0


@dataclass(frozen=True)
class SceneGraph:
    """Objects as the records of ``objects.json``; rooms as a :class:`RoomMap`; relations as (kind, a, b) with
    kind ``in`` (object a in room b), ``on`` (object a on object b) or ``near`` (objects a and b of one room,
centroids within ``near``; not for a pair already "on": a scene graph holds one edge per pair)."""

    objects: list[dict]
    rooms: RoomMap
    relations: list[tuple[str, int, int]] = field(default_factory=list)

    def counts(self) -> dict[str, int]:
        kinds = [r[0] for r in self.relations]
        return {"objects": len(self.objects), "rooms": len(self.rooms.names), "in": kinds.count("in"),
                "on": kinds.count("on"), "near": kinds.count("near")}


def box_bounds(record: dict) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned (min, max) of an object record's oriented box."""
    box = record["box"]
    rot, half = np.asarray(box["rotation"], np.float64), np.asarray(box["extent"], np.float64) / 2
    reach = np.abs(rot) @ half
    centre = np.asarray(box["center"], np.float64)
    return centre - reach, centre + reach


def _on(a: tuple[np.ndarray, np.ndarray], b: tuple[np.ndarray, np.ndarray], centre_a: np.ndarray) -> bool:
    """Object a rests on b: a's bottom near b's top, a's centre above b's footprint, a mostly above b."""
    (alo, ahi), (blo, bhi) = a, b
    return (abs(alo[2] - bhi[2]) <= ON_GAP and ahi[2] > bhi[2] and
            bool(np.all((centre_a[:2] >= blo[:2]) & (centre_a[:2] <= bhi[:2]))))


def build_scene_graph(objects: list[dict], rooms: RoomMap, *, near: float = NEAR) -> SceneGraph:
    """Relations of ``objects`` among themselves and with ``rooms``."""
    if not np.isfinite(near) or near <= 0:
        raise ConfigError(f"--near must be a positive distance in metres, got {near}")
    centroids = np.array([o["centroid"] for o in objects], np.float64).reshape(-1, 3)
    room_of = rooms.room_at(centroids[:, :2]) if len(objects) else np.zeros(0, np.int32)
    relations: list[tuple[str, int, int]] = [("in", int(o["id"]), int(r)) for o, r in zip(objects, room_of,
                                                                                          strict=True) if r >= 0]
    bounds = [box_bounds(o) for o in objects]
    for i, a in enumerate(objects):
        for j, b in enumerate(objects):
            if i != j and _on(bounds[i], bounds[j], centroids[i]):
                relations.append(("on", int(a["id"]), int(b["id"])))
    resting = {frozenset((a, b)) for kind, a, b in relations if kind == "on"}  # one edge per pair: "on" wins
    for i in range(len(objects)):
        for j in range(i + 1, len(objects)):
            pair = frozenset((int(objects[i]["id"]), int(objects[j]["id"])))
            if pair not in resting and room_of[i] == room_of[j] and \
                    np.linalg.norm(centroids[i] - centroids[j]) <= near:
                relations.append(("near", int(objects[i]["id"]), int(objects[j]["id"])))
    return SceneGraph(objects, rooms, relations)


def write_dsg(path: Path, graph: SceneGraph) -> None:
    """``graph`` as a spark-dsg DynamicSceneGraph file (JSON when ``path`` ends in .json)."""
    import spark_dsg as dsg

    g = dsg.DynamicSceneGraph()
    labels: dict[int, str] = {}
    for o in graph.objects:
        attrs = dsg.ObjectNodeAttributes()
        lo, hi = box_bounds(o)
        attrs.name = f"{o['class']} {o['id']}"
        attrs.position = np.asarray(o["centroid"], np.float64)
        attrs.semantic_label = int(o["class_id"])
        attrs.bounding_box = dsg.BoundingBox((hi - lo).astype(np.float32), ((hi + lo) / 2).astype(np.float32))
        attrs.metadata.add({"class": o["class"], "points": int(o["points"]), "confidence": float(o["confidence"]),
                            "sightings": int(o["sightings"])})
        labels[int(o["class_id"])] = str(o["class"])
        g.add_node(dsg.DsgLayers.OBJECTS, dsg.NodeSymbol("O", int(o["id"])), attrs)
    for r, name in enumerate(graph.rooms.names):
        centre, (lo, hi), area = graph.rooms.footprint(r)
        attrs = dsg.RoomNodeAttributes()
        attrs.name = name
        attrs.position = np.array([centre[0], centre[1], graph.rooms.floor_z])
        attrs.bounding_box = dsg.BoundingBox(np.array([*(hi - lo), 0.0], np.float32),
                                             np.array([*centre, graph.rooms.floor_z], np.float32))
        attrs.metadata.add({"area_m2": round(area, 3), "source": graph.rooms.source})
        g.add_node(dsg.DsgLayers.ROOMS, dsg.NodeSymbol("R", r), attrs)
    for kind, a, b in graph.relations:
        info = dsg.EdgeAttributes()
        info.metadata.add({"relation": kind})
        target = dsg.NodeSymbol("R", b) if kind == "in" else dsg.NodeSymbol("O", b)
        if kind == "in":
            g.insert_edge(target, dsg.NodeSymbol("O", a), info)  # rooms are the objects' parents
        else:
            g.insert_edge(dsg.NodeSymbol("O", a), target, info)
    g.set_labelspace(dsg.Labelspace(labels), dsg.DsgLayers.OBJECTS)
    g.save(str(path), include_mesh=False)
