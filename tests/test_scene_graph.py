"""Scene graphs (issue 35): rooms from a layout or a grid's room segmentation, relations (in, on, near), and the
spark-dsg file Hydra's tools read, loaded back with spark_dsg."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from semmap.cli import app
from semmap.errors import ConfigError, FormatError
from semmap.io.map_files import save_map
from semmap.products.export import export_scene_graph
from semmap.products.navgrid import NavigationGrid
from semmap.products.rooms import rooms_from_boxes, rooms_from_grid
from semmap.products.scene_graph import build_scene_graph, write_dsg

spark_dsg = pytest.importorskip("spark_dsg")


def record(oid: int, cls: str, class_id: int, lo, hi) -> dict:
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    return {"id": oid, "class": cls, "class_id": class_id, "confidence": 0.9, "centroid": list((lo + hi) / 2),
            "box": {"center": list((lo + hi) / 2), "rotation": np.eye(3).tolist(), "extent": list(hi - lo)},
            "points": 100, "sightings": 3}


OBJECTS = [record(1, "table", 5, (1.0, 1.0, 0.0), (2.0, 2.0, 0.75)),
           record(2, "cup", 9, (1.4, 1.4, 0.76), (1.5, 1.5, 0.86)),
           record(3, "chair", 4, (1.0, 2.1, 0.0), (1.5, 2.6, 0.9)),
           record(4, "sofa", 7, (5.0, 1.0, 0.0), (6.5, 2.0, 0.8))]
TWO_ROOMS = [("kitchen", np.array([0.0, 0.0, 0.0]), np.array([4.0, 4.0, 2.5])),
             ("living room", np.array([4.0, 0.0, 0.0]), np.array([8.0, 4.0, 2.5]))]


def test_relations_in_on_near():
    g = build_scene_graph(OBJECTS, rooms_from_boxes(TWO_ROOMS))
    rel = set(g.relations)
    assert {("in", 1, 0), ("in", 2, 0), ("in", 3, 0), ("in", 4, 1)} <= rel
    assert ("on", 2, 1) in rel and ("on", 1, 2) not in rel and ("on", 3, 1) not in rel
    assert ("near", 1, 2) not in rel  # "on" already relates them
    assert ("near", 1, 3) in rel and not any(k == "near" and 4 in (a, b) for k, a, b in rel)  # sofa: other room
    with pytest.raises(ConfigError, match="--near"):
        build_scene_graph(OBJECTS, rooms_from_boxes(TWO_ROOMS), near=float("nan"))


def two_room_grid(door: float) -> NavigationGrid:
    """8 m x 4 m at 10 cm: walls around, a wall at x = 4 m with a door ``door`` metres wide."""
    occ = np.zeros((80, 40), np.int8)
    occ[[0, -1], :] = occ[:, [0, -1]] = 100
    occ[40, :] = 100
    occ[40, 20:20 + round(door / 0.1)] = 0
    occ[60:62, 10:12] = 100  # a table in the second room
    return NavigationGrid(occ, occ.copy(), np.zeros(2), 0.1, 0.0, (0.1, 1.5), {})


def test_room_segmentation_splits_at_doors():
    rooms = rooms_from_grid(two_room_grid(0.8), door_width=1.0)
    assert len(rooms.names) == 2
    a, b = rooms.room_at(np.array([[2.0, 2.0], [6.0, 2.0]]))
    assert a != b and a >= 0 and b >= 0
    assert rooms.room_at(np.array([[6.05, 1.05]]))[0] == b  # the table's cell joins its room
    assert len(rooms_from_grid(two_room_grid(2.0), door_width=1.0).names) == 1  # an opening, not a door


def test_dsg_file_loads_in_spark_dsg(tmp_path):
    g = build_scene_graph(OBJECTS, rooms_from_boxes(TWO_ROOMS))
    path = tmp_path / "scene_graph.json"
    write_dsg(path, g)
    loaded = spark_dsg.DynamicSceneGraph.load(str(path))
    objects = loaded.get_layer(spark_dsg.DsgLayers.OBJECTS)
    rooms = loaded.get_layer(spark_dsg.DsgLayers.ROOMS)
    assert objects.num_nodes() == 4 and rooms.num_nodes() == 2
    names = {n.attributes.name for n in objects.nodes}
    assert names == {"table 1", "cup 2", "chair 3", "sofa 4"}
    assert {n.attributes.name for n in rooms.nodes} == {"kitchen", "living room"}
    cup = loaded.get_node(spark_dsg.NodeSymbol("O", 2))
    assert np.allclose(cup.attributes.position, [1.45, 1.45, 0.81]) and cup.attributes.semantic_label == 9
    assert loaded.has_edge(spark_dsg.NodeSymbol("R", 1), spark_dsg.NodeSymbol("O", 4))
    assert loaded.num_edges() == len(g.relations)


def test_export_scene_graph_of_a_run(tmp_path):
    from test_products import room_map

    run = tmp_path / "run"
    run.mkdir()
    save_map(run / "map.semmap", room_map())
    out = tmp_path / "graph"
    with pytest.raises(FormatError, match=r"no objects\.json"):
        export_scene_graph(run, out)
    doc = {"format": "semmap-objects", "version": 1, "up": [0, 0, 1],
           "objects": [record(1, "chair", 2, (1.0, 1.0, 0.2), (1.2, 1.2, 0.6))]}
    (run / "objects.json").write_text(json.dumps(doc))
    r = CliRunner().invoke(app, ["export", "scene-graph", str(run), "--out", str(out)])
    assert r.exit_code == 0, r.output
    summary = json.loads((out / "graph.json").read_text())
    assert summary["rooms_from"] == "grid" and summary["counts"]["objects"] == 1
    assert spark_dsg.DynamicSceneGraph.load(str(out / "scene_graph.json")).num_nodes() >= 1
