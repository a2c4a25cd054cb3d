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
from semmap.products.changes import confirmed_by_space, object_changes, voxel_changes
from semmap.types import EMPTY_LABEL, LabelSet, Observation, TopKProbs

RES = 0.1
LABELS = LabelSet.generic(4)


def scene(box_at: tuple[float, float] | None, *, floor_to: float = 2.0) -> SemanticOctoMap:
    """A floor (class 1) and a 0.2 m box (class 2) standing at ``box_at``, seen from above."""
    xs = np.arange(RES / 2, floor_to, RES)
    floor = np.stack(np.meshgrid(xs, xs, [0.05], indexing="ij"), -1).reshape(-1, 3)
    parts, labels = [floor], [np.full(len(floor), 1)]
    if box_at is not None:
        b = np.arange(RES / 2, 0.2, RES)
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


def test_unmatched_objects_need_free_space_in_the_other_map():
    """A box that went (too far to match) is reported gone and new; an object only the first map picked out but whose
    space the second still saw occupied (a patch of floor) is no change."""
    def rec(i, cls, xyz):
        return {"id": i, "class": cls, "centroid": list(xyz)}

    before = [rec(1, LABELS.names[2], (0.5, 0.5, 0.15)), rec(2, LABELS.names[1], (1.0, 1.0, 0.05))]
    after = [rec(3, LABELS.names[2], (1.5, 1.5, 0.15))]
    ch = object_changes(before, after, match_radius=0.5)
    assert len(ch["disappeared"]) == 2 and len(ch["appeared"]) == 1
    kept = confirmed_by_space(ch, scene((0.4, 0.4)), scene((1.4, 1.4)))
    assert [r["before"] for r in kept["disappeared"]] == [1] and [r["after"] for r in kept["appeared"]] == [3]


def test_diff_command(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    for folder, m in ((a, scene((0.4, 0.4))), (b, scene((1.4, 1.4)))):
        folder.mkdir()
        save_map(folder / "map.semmap", m)
    out = tmp_path / "diff"
    r = CliRunner().invoke(app, ["diff", str(a), str(b), "--out", str(out)])
    assert r.exit_code == 0, r.output
    summary = json.loads((out / "diff.json").read_text())
    cloud = read_ply(out / "diff.ply")
    assert len(cloud) == sum(summary["voxels"][k] for k in ("appeared", "disappeared", "relabelled"))
    assert (out / "diff.png").stat().st_size > 1000 and summary["objects"] is None
    coarse = tmp_path / "coarse.semmap"
    save_map(coarse, SemanticOctoMap(0.2, label_set=LABELS))
    r = CliRunner().invoke(app, ["diff", str(a / "map.semmap"), str(coarse), "--out", str(tmp_path / "x")])
    assert r.exit_code != 0 and "different resolutions" in str(r.exception)


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
