"""The same simulated scene a while later (issue 36): objects moved, removed and added as recorded, the ground
truth of the changed scene regenerated from its folder, and bad requests refused in one line."""

from __future__ import annotations

import json

import numpy as np
import pytest

from semmap.datasets.simulated import scene_of_folder
from semmap.errors import SimulationError
from semmap.sim.changes import CLEARANCE, change_scene
from semmap.sim.export import simulate_sequence
from semmap.sim.scene import generate_scene


@pytest.fixture(scope="module")
def before():
    return generate_scene(0, "office", "medium")


def test_changes_happen_as_recorded(before):
    after, record = change_scene(before, 3, seed=1)
    assert [r["change"] for r in record] == ["move", "remove", "add"]
    moved, removed, added = record
    shift = np.array(moved["to"]) - np.array(moved["from"])
    a = before.vertices[np.unique(before.triangles[before.tri_instance == moved["id"]])]
    b = after.vertices[np.unique(after.triangles[after.tri_instance == moved["id"]])]
    assert np.allclose(b, a + shift, atol=1e-5) and np.linalg.norm(shift) > 0.1
    assert not np.any(after.tri_instance == removed["id"])
    assert removed["id"] not in {o.instance_id for o in after.objects}
    copy = after.tri_instance == added["new_id"]
    assert copy.sum() == (before.tri_instance == added["id"]).sum()
    assert set(after.tri_class[copy].tolist()) == {before.object(added["id"]).class_id}


def test_changed_objects_keep_clear_of_the_others(before):
    after, record = change_scene(before, 6, seed=2)
    placed = {r.get("new_id", r["id"]) for r in record if r["change"] != "remove"}
    for pid in placed:
        o = after.object(pid)
        for other in after.objects:
            if other.instance_id == pid:
                continue
            apart = np.any(o.bbox_max[:2] + CLEARANCE <= other.bbox_min[:2] + 1e-6) or \
                np.any(other.bbox_max[:2] + CLEARANCE <= o.bbox_min[:2] + 1e-6)
            assert apart, (o.class_name, other.class_name)


def test_same_seed_same_changes(before):
    assert change_scene(before, 3, seed=5)[1] == change_scene(before, 3, seed=5)[1]
    assert change_scene(before, 3, seed=5)[1] != change_scene(before, 3, seed=6)[1]


def test_folder_regenerates_the_changed_scene(tmp_path):
    root = simulate_sequence(tmp_path / "later", scene_seed=1, frames=1, image_size=(40, 30), changes=2,
                             size="small")
    record = json.loads((root / "changes.json").read_text())
    scene = scene_of_folder(root)
    assert scene is not None and scene.params["changes"] == 2 and len(record) == 2
    assert {o["id"] for o in json.loads((root / "objects.json").read_text())} == \
        {o.instance_id for o in scene.objects}


def test_bad_requests_are_refused(before):
    with pytest.raises(SimulationError, match="changes must be"):
        change_scene(before, -1)
    with pytest.raises(SimulationError, match="fewer --changes"):
        change_scene(before, 50)
