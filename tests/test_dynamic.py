"""Dynamic classes (issue 36, item 4): a person walking through a simulated scene leaves no occupied voxel where
only the person ever was, at any frame, and the static objects it passed stay as the map without the person has
them (>= 99 % of its occupied cells); clear-only rays clear free space; the simulator's walking people."""

from __future__ import annotations

import numpy as np
import pytest

from semmap.config import MappingConfig
from semmap.errors import ConfigError
from semmap.keys import coords_to_keys, keys_to_coords, pack_keys, unpack_keys
from semmap.labels import INDOOR_LABELS
from semmap.maps.point_map import SemanticPointMap
from semmap.maps.semantic_octomap import FREE, OCCUPIED, UNKNOWN, SemanticOctoMap
from semmap.maps.voxel_grid import SemanticVoxelGrid
from semmap.pipeline import Mapper
from semmap.sim.export import simulate_frames
from semmap.sim.ground_truth import gt_voxels
from semmap.sim.people import add_people, person_cells
from semmap.sim.scene import generate_scene
from semmap.sim.trajectory import make_trajectory
from semmap.types import CameraIntrinsics, TopKProbs

RES = 0.05
FPS = 3.0  # 30 frames span 10 s: the person crosses the view while the camera goes round
FRAMES = 30
PERSON = INDOOR_LABELS.id_of("person")
CAMERA = CameraIntrinsics(80, 60, 65.0, 65.0, 39.5, 29.5)


@pytest.fixture(scope="module")
def walk():
    """The default office (it has no standing person) with one walker, rendered with and without it."""
    scene = generate_scene(0, "office", "medium")
    poses = make_trajectory(scene, "loop", FRAMES, seed=0, fps=FPS)
    with_person = list(simulate_frames(scene, poses, noise=False, seed=0, intrinsics=CAMERA, people=1, fps=FPS))
    without = list(simulate_frames(scene, poses, noise=False, seed=0, intrinsics=CAMERA, people=0, fps=FPS))
    shown, walkers = add_people(scene, 1, 0, poses[:, :3, 3], FPS)
    static = pack_keys(gt_voxels(scene, RES).keys)
    person = person_cells(shown, walkers, np.arange(FRAMES) / FPS, RES)
    only = np.setdiff1d(person, static)  # where only the person ever was
    return with_person, without, keys_to_coords(unpack_keys(only), RES)


@pytest.fixture(scope="module")
def reference(walk):
    """Occupied cells of the OctoMap of the frames without the person."""
    return _occupied(_map(walk[1], (PERSON,))[0])


def _map(frames, dynamic, kind: str = "octomap", watch: np.ndarray | None = None):
    """The map of ``frames`` (their true labels as class sets) and the most of ``watch`` occupied after a frame."""
    m = {"octomap": lambda: SemanticOctoMap(RES, label_set=INDOOR_LABELS),
         "voxelgrid": lambda: SemanticVoxelGrid(RES, label_set=INDOOR_LABELS, free_space=True),
         "points": lambda: SemanticPointMap(RES, label_set=INDOOR_LABELS, keyframes_only=False)}[kind]()
    mapper = Mapper([m], min_depth=0.1, max_depth=8.0, dynamic=dynamic)
    most = 0
    for f in frames:
        mapper.integrate(f, f.T_world_cam, TopKProbs.from_hard_labels(f.labels, 0.9, len(INDOOR_LABELS), 3))
        if watch is not None:
            most = max(most, int((m.state_at(watch) == OCCUPIED).sum()))
    return m, most


def _occupied(m) -> np.ndarray:
    return pack_keys(coords_to_keys(m.cloud().centers, RES))


def _held_at(m, centres: np.ndarray) -> int:
    return int(np.isin(pack_keys(coords_to_keys(centres, RES)), _occupied(m)).sum())


@pytest.mark.slow
def test_the_walker_is_seen_and_labelled_person(walk):
    with_person, without, only = walk
    seen = [int((f.labels == PERSON).sum()) for f in with_person]
    assert sum(s > 100 for s in seen) >= 4 and len(only) > 1000
    assert not any((f.labels == PERSON).any() for f in without)


@pytest.mark.slow
def test_a_walking_person_never_occupies_a_voxel_and_the_static_map_stays(walk, reference):
    with_person, _, only = walk
    m, most = _map(with_person, (PERSON,), watch=only)
    assert most == 0  # after no frame is a voxel where only the person was occupied
    kept = np.isin(reference, _occupied(m)).mean()
    assert kept >= 0.99, kept
    _, most_without = _map(with_person, (), watch=only)  # the same frames, the person not dynamic
    assert most_without > 50


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["points", "voxelgrid"])
def test_the_grids_leave_dynamic_points_out(walk, reference, kind):
    with_person, without, only = walk
    if kind == "points":  # (a voxel grid with free space is occupied where its OctoMap is)
        reference = _occupied(_map(without, (PERSON,), kind)[0])
    m = _map(with_person, (PERSON,), kind)[0]
    assert _held_at(m, only) == 0
    assert np.isin(reference, _occupied(m)).mean() >= 0.99
    if kind == "points":  # no free space to clear it: without the class dynamic, the person stays in the map
        assert _held_at(_map(with_person, (), kind)[0], only) > 100


def test_clear_only_rays_clear_free_space_but_never_hit():
    wall = np.stack(np.meshgrid(np.linspace(-1.2, 1.2, 49), np.linspace(-1.2, 1.2, 49), [3.0]), -1).reshape(-1, 3)
    person = np.stack(np.meshgrid(np.linspace(-0.4, 0.4, 17), np.linspace(-0.4, 0.4, 17), [1.5]), -1).reshape(-1, 3)
    m = SemanticOctoMap(RES)
    m.insert_points(person, np.zeros(3))  # someone stood there once
    assert (m.state_at(person) == OCCUPIED).all()
    for _ in range(4):  # later they walk in front of a wall, seen as clear-only points
        stats = m.insert_points(wall[:0], np.zeros(3), clear=wall)
    assert stats.clear_rays > 0 and stats.hits == 0
    assert (m.state_at(person) == FREE).all() and (m.state_at(wall) == UNKNOWN).all()
    plain = SemanticOctoMap(RES)
    plain.insert_points(wall, np.zeros(3))
    both = SemanticOctoMap(RES)
    both.insert_points(wall, np.zeros(3), clear=np.zeros((0, 3)))
    assert np.array_equal(plain.cells().packed, both.cells().packed)  # no clear-only point: OctoMap's insert


def test_dynamic_names_from_the_option():
    assert MappingConfig(dynamic="person,chair").dynamic == ("person", "chair")
    assert MappingConfig(dynamic="none").dynamic == () and MappingConfig().dynamic == ("person",)


def test_an_unknown_dynamic_class_is_refused_in_one_line(tmp_path):
    from semmap.config import InputConfig, OutputConfig, RunConfig
    from semmap.run.prepare import dynamic_classes

    config = RunConfig(input=InputConfig(dataset=tmp_path), output=OutputConfig(out=tmp_path / "o"),
                       mapping=MappingConfig(dynamic="person,unicorn"))
    with pytest.raises(ConfigError, match="--dynamic: class 'unicorn'"):
        dynamic_classes(config, INDOOR_LABELS)
    default = RunConfig(input=InputConfig(dataset=tmp_path), output=OutputConfig(out=tmp_path / "o"))
    assert dynamic_classes(default, INDOOR_LABELS) == (PERSON,) and dynamic_classes(default, None) == ()


@pytest.mark.slow
def test_simulate_people_keeps_the_static_scene_and_its_ground_truth(tmp_path):
    import json

    from semmap.datasets.simulated import scene_of_folder
    from semmap.sim.export import simulate_sequence

    root = simulate_sequence(tmp_path / "seq", size="medium", frames=3, image_size=(80, 60), people=1, noise=False)
    info = json.loads((root / "scene.json").read_text())
    assert [p["class"] for p in info["people"]] == ["person"] and len(info["people"][0]["path"]) > 2
    scene = scene_of_folder(root)  # the static scene, regenerated: the walker is not part of it
    assert scene is not None and scene.n_triangles == info["n_triangles"]
    assert "person" not in {o["class"] for o in json.loads((root / "objects.json").read_text())}
    with pytest.raises(Exception, match="--people"):
        simulate_sequence(tmp_path / "bad", frames=1, people=9)


def test_decay_lets_unseen_evidence_fade_so_that_one_miss_clears_it():
    wall = np.stack(np.meshgrid(np.linspace(-0.4, 0.4, 17), np.linspace(-0.4, 0.4, 17), [1.5]), -1).reshape(-1, 3)
    behind = np.stack(np.meshgrid(np.linspace(-1.2, 1.2, 49), np.linspace(-1.2, 1.2, 49), [3.0]), -1).reshape(-1, 3)
    elsewhere = wall + np.array([0.0, 0.0, -3.0])  # a view away from the wall (behind the sensor)
    held = {}
    for decay in (0.0, 0.5):
        m = SemanticOctoMap(RES, decay=decay)
        m.insert_points(wall, np.zeros(3))
        for _ in range(4):
            m.insert_points(elsewhere, np.zeros(3))
        lo = m._logodds[m._slots_of(wall)]
        held[decay] = lo
        m.insert_points(behind, np.zeros(3))  # one scan through the wall's place
        assert (m.state_at(wall) == (OCCUPIED if decay == 0.0 else FREE)).all()
    assert np.allclose(held[0.0], m.occupancy.hit_log) and np.allclose(held[0.5], m.occupancy.hit_log / 16)
    with pytest.raises(ConfigError, match="--decay"):
        SemanticOctoMap(RES, decay=1.0)
