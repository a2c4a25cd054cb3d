"""What changed (issue 36, deliverable 3): voxels that appeared or disappeared only where both maps saw the space,
objects matched by class and position, and `semmap diff` writing diff.json / diff.ply / diff.png."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from semmap.cli import app
from semmap.errors import ConfigError
from semmap.io.map_files import save_map
from semmap.io.ply import read_ply
from semmap.maps.semantic_octomap import SemanticOctoMap
from semmap.products.changes import diff_objects, object_changes, voxel_changes
from semmap.types import EMPTY_LABEL, LabelSet, Observation, TopKProbs

RES = 0.1
LABELS = LabelSet.generic(4)


def scene(box_at: tuple[float, float] | None, *, floor_to: float = 2.0, side: float = 0.2) -> SemanticOctoMap:
    """A floor (class 1) and a ``side`` m box (class 2) standing at ``box_at``, seen from above."""
    xs = np.arange(RES / 2, floor_to, RES)
    floor = np.stack(np.meshgrid(xs, xs, [0.05], indexing="ij"), -1).reshape(-1, 3)
    parts, labels = [floor], [np.full(len(floor), 1)]
    if box_at is not None:
        b = np.arange(RES / 2, side, RES)
        box = np.stack(np.meshgrid(b + box_at[0], b + box_at[1], b + 0.1, indexing="ij"), -1).reshape(-1, 3)
        parts.append(box)
        labels.append(np.full(len(box), 2))
    pts = np.concatenate(parts).astype(np.float32)
    lab = np.full((len(pts), 3), EMPTY_LABEL, np.uint16)
    lab[:, 0] = np.concatenate(labels)
    probs = np.zeros((len(pts), 3), np.float32)
    probs[:, 0] = 0.9
    m = SemanticOctoMap(RES, label_set=LABELS)
    for origin in ([0.5, 0.5, 1.5], [1.5, 1.5, 1.5], [0.5, 1.5, 1.5], [1.5, 0.5, 1.5]):
        m.integrate(Observation(pts, np.array(origin), np.full((len(pts), 3), 99, np.uint8), TopKProbs(lab, probs)))
    return m


def test_a_moved_box_appears_and_disappears():
    c = voxel_changes(scene((0.4, 0.4)), scene((1.4, 1.4)))
    n = c.counts()
    assert 4 <= n["appeared"] <= 8 and 4 <= n["disappeared"] <= 8
    assert np.all(np.linalg.norm(c.centers["appeared"][:, :2] - 1.5, axis=1) < 0.3)
    assert np.all(np.linalg.norm(c.centers["disappeared"][:, :2] - 0.5, axis=1) < 0.3)
    assert set(c.labels["appeared"].tolist()) == {2}


def test_unseen_space_is_no_change():
    small = scene(None, floor_to=1.0)  # the second recording saw only a quarter of the floor
    c = voxel_changes(scene((1.4, 1.4)), small)
    assert c.counts()["disappeared"] == 0 and c.unobserved > 0


def test_objects_matched_by_class_and_position():
    def rec(i, cls, x):
        return {"id": i, "class": cls, "centroid": [x, 0.0, 0.5]}

    before = [rec(1, "chair", 0.0), rec(2, "chair", 3.0), rec(3, "lamp", 5.0)]
    after = [rec(7, "chair", 0.05), rec(8, "chair", 3.6), rec(9, "plant", 5.0)]
    ch = object_changes(before, after, match_radius=1.0, move_threshold=0.2)
    assert [(r["before"], r["after"]) for r in ch["stayed"]] == [(1, 7)]
    assert [(r["before"], r["after"]) for r in ch["moved"]] == [(2, 8)]
    assert [r["before"] for r in ch["disappeared"]] == [3] and [r["after"] for r in ch["appeared"]] == [9]
    with pytest.raises(ConfigError, match="match radius"):
        object_changes(before, after, match_radius=float("nan"))


def box_record(i: int, xy: tuple[float, float], cls: str = LABELS.names[2], side: float = 0.3) -> dict:
    """An objects.json record of the ``side`` m box of :func:`scene` standing with its corner at ``xy``."""
    c = [xy[0] + side / 2, xy[1] + side / 2, 0.1 + side / 2]
    return {"id": i, "class": cls, "centroid": c, "points": 27,
            "box": {"center": c, "rotation": np.eye(3).tolist(), "extent": [side] * 3}}


def test_a_long_move_is_one_move():
    """A box carried farther than the match radius: its old place seen free after, its new place free before, so
    it moved (not one object gone and another come)."""
    ch = diff_objects([box_record(1, (0.4, 0.4))], [box_record(2, (1.4, 1.4))], scene((0.4, 0.4), side=0.3),
                      scene((1.4, 1.4), side=0.3), match_radius=0.5)
    assert [(r["before"], r["after"]) for r in ch["moved"]] == [(1, 2)]
    assert ch["appeared"] == [] and ch["disappeared"] == [] and ch["unknown"] == []
    assert ch["moved"][0]["distance_m"] > 1.0


def test_an_object_missing_in_one_recording_is_no_change_without_evidence():
    """An object the second walk never looked at is of unknown fate, not gone; one whose place the second map saw
    occupied (it picked out no object there) is not gone either; one whose place it saw free is gone."""
    unseen = diff_objects([box_record(1, (1.4, 1.4))], [], scene((1.4, 1.4), side=0.3), scene(None, floor_to=1.0))
    assert unseen["disappeared"] == []
    assert [(r["before"], r["reason"]) for r in unseen["unknown"]] == [(1, "unobserved")]
    kept = diff_objects([box_record(1, (0.4, 0.4))], [], scene((0.4, 0.4), side=0.3), scene((0.4, 0.4), side=0.3))
    assert kept["disappeared"] == [] and [r["reason"] for r in kept["unknown"]] == ["occupied"]
    gone = diff_objects([box_record(1, (0.4, 0.4))], [], scene((0.4, 0.4), side=0.3), scene(None))
    assert [r["before"] for r in gone["disappeared"]] == [1] and gone["unknown"] == []


def test_a_removed_object_the_object_map_missed_is_found_in_the_voxels():
    """A 0.4 m box no object record covers that went: a cluster of disappeared voxels of its class is reported
    (``source`` voxels); where an object record covers it, the objects decide (here: no change reported twice)."""
    big, empty = scene((0.4, 0.4), side=0.4), scene(None)
    ch = diff_objects([], [], big, empty)
    assert [(r["class"], r["source"]) for r in ch["disappeared"]] == [(LABELS.names[2], "voxels")]
    assert np.linalg.norm(np.array(ch["disappeared"][0]["at"][:2]) - 0.6) < 0.15
    rec = {**box_record(1, (0.4, 0.4)), "centroid": [0.6, 0.6, 0.3],
           "box": {"center": [0.6, 0.6, 0.3], "rotation": np.eye(3).tolist(), "extent": [0.4, 0.4, 0.4]}}
    ch = diff_objects([rec], [], big, empty)
    assert [(r.get("source"), r["before"]) for r in ch["disappeared"]] == [(None, 1)]


def test_a_move_pairs_like_objects_not_the_nearest():
    """Two chairs gone and two come, far apart: each pairs with the one of its colour, not the nearer one."""
    from semmap.products.changes import ObjectEvidence

    def rec(i, x):
        return {"id": i, "class": "chair", "centroid": [x, 0.0, 0.5], "points": 100}

    red, blue = [0.8, 0.1, 0.1], [0.1, 0.1, 0.8]
    ev = (ObjectEvidence(["gone", "gone"], np.array([red, blue])),
          ObjectEvidence(["gone", "gone"], np.array([blue, red])))
    ch = object_changes([rec(1, 0.0), rec(2, 5.0)], [rec(3, 2.0), rec(4, 3.5)], evidence=ev)
    assert sorted((r["before"], r["after"]) for r in ch["moved"]) == [(1, 4), (2, 3)]


def test_diff_command(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    for folder, m in ((a, scene((0.4, 0.4), side=0.3)), (b, scene((1.4, 1.4), side=0.3))):
        folder.mkdir()
        save_map(folder / "map.semmap", m)
    out = tmp_path / "diff"
    r = CliRunner().invoke(app, ["diff", str(a), str(b), "--out", str(out)])
    assert r.exit_code == 0, r.output
    summary = json.loads((out / "diff.json").read_text())
    cloud = read_ply(out / "diff.ply")
    assert len(cloud) == sum(summary["voxels"][k] for k in ("appeared", "disappeared", "relabelled"))
    assert (out / "diff.png").stat().st_size > 1000 and summary["objects"] is None
    for folder, rec in ((a, box_record(1, (0.4, 0.4))), (b, box_record(2, (1.4, 1.4)))):  # a 1.4 m move
        doc = {"format": "semmap-objects", "version": 1, "up": [0, 0, 1], "objects": [{**rec, "sightings": 3}]}
        (folder / "objects.json").write_text(json.dumps(doc))
    r = CliRunner().invoke(app, ["diff", str(a), str(b), "--out", str(tmp_path / "diff2")])
    assert r.exit_code == 0, r.output
    objects = json.loads((tmp_path / "diff2" / "diff.json").read_text())["object_changes"]
    assert [(m["before"], m["after"]) for m in objects["moved"]] == [(1, 2)] and "1 moved" in r.output
    coarse = tmp_path / "coarse.semmap"
    save_map(coarse, SemanticOctoMap(0.2, label_set=LABELS))
    r = CliRunner().invoke(app, ["diff", str(a / "map.semmap"), str(coarse), "--out", str(tmp_path / "x")])
    assert r.exit_code != 0 and "different resolutions" in str(r.exception)


@pytest.mark.slow
def test_diff_finds_the_simulated_changes():
    """Two walks through one simulated room, the second after `simulate --changes`: the moved object's voxels
    disappear where it stood and appear where it went, as changes.json records."""
    from semmap.datasets.simulated import SimulatedDataset
    from semmap.pipeline import Mapper
    from semmap.sim.changes import change_scene
    from semmap.sim.scene import generate_scene
    from semmap.sim.trajectory import make_trajectory
    from semmap.types import CameraIntrinsics

    camera = CameraIntrinsics(160, 120, 131.25, 131.25, 79.5, 59.5)
    before = generate_scene(0, "office", "small")
    after, record = change_scene(before, 1, seed=1)  # one move
    maps = []
    for scene in (before, after):
        m = SemanticOctoMap(0.05, label_set=scene.label_set)
        mapper = Mapper([m], min_depth=0.1, max_depth=6.0)
        for f in SimulatedDataset(scene, make_trajectory(before, "orbit", 12, seed=0, fps=1), intrinsics=camera,
                                  noise=False):
            mapper.integrate_arrays(f.rgb, f.depth, f.intrinsics, f.T_world_cam, f.labels)
        maps.append(m)
    c = voxel_changes(*maps)
    move = record[0]
    near_to = np.linalg.norm(c.centers["appeared"][:, :2] - move["to"][:2], axis=1) < 0.5
    near_from = np.linalg.norm(c.centers["disappeared"][:, :2] - move["from"][:2], axis=1) < 0.5
    assert near_to.sum() >= 10 and near_from.sum() >= 10
    assert near_to.mean() > 0.5 and near_from.mean() > 0.5  # most changes are the moved object
