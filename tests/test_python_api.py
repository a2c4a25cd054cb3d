"""The Python API for a user's own loop: lazy top-level names, frames from plain arrays, the map queries
(``class_at``, ``voxels_of_class``), one save/load for every map, and examples/python_api.py run end to end."""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import semmap
from semmap.errors import ConfigError, FormatError
from semmap.frame_arrays import class_sets, frame_from_arrays
from semmap.maps.base import SemanticMap, voxels_of_class
from semmap.maps.registry import MapKind
from semmap.pipeline import Mapper
from semmap.types import EMPTY_LABEL, CameraIntrinsics, LabelSet, TopKProbs

ROOT = Path(__file__).resolve().parents[1]
CAM = CameraIntrinsics(64, 48, 50.0, 50.0, 31.5, 23.5)


def test_import_semmap_loads_no_subpackage_and_every_public_name_resolves():
    code = ("import sys, semmap; heavy = [m for m in sys.modules if m.startswith(('semmap.pipeline', 'semmap.maps', "
            "'semmap.datasets', 'semmap.perception', 'torch'))]; print(heavy)")
    env = {**os.environ, "PYTHONPATH": str(ROOT / "src")}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, env=env).stdout
    assert out.strip() == "[]"
    for name in semmap.__all__:
        assert getattr(semmap, name) is not None
    assert semmap.Mapper is Mapper and semmap.voxels_of_class is voxels_of_class
    assert set(semmap.__all__) <= set(dir(semmap))
    with pytest.raises(AttributeError, match="no_such_name"):
        _ = semmap.no_such_name


def wall_frame(label: int = 2, depth: float = 2.013):
    """A flat wall ``depth`` metres in front of a camera at the origin looking along +z, every pixel ``label``."""
    rgb = np.full((CAM.height, CAM.width, 3), 90, np.uint8)
    depth_m = np.full((CAM.height, CAM.width), depth, np.float32)
    return rgb, depth_m, CAM.K, np.eye(4), np.full((CAM.height, CAM.width), label, np.int64)


def make_map(kind: MapKind, labels: LabelSet) -> SemanticMap:
    if kind == MapKind.OCTOMAP:
        return semmap.SemanticOctoMap(0.05, label_set=labels)
    if kind == MapKind.VOXELGRID:
        return semmap.SemanticVoxelGrid(0.05, label_set=labels, free_space=True)
    if kind == MapKind.TSDF:
        return semmap.TsdfMap(0.05, label_set=labels)
    return semmap.SemanticPointMap(0.02, label_set=labels, keyframes_only=False)


@pytest.mark.parametrize("kind", list(MapKind))
def test_class_at_answers_what_the_cloud_shows_and_nothing_elsewhere(kind):
    labels = LabelSet.generic(5)
    m = make_map(kind, labels)
    mapper = Mapper([m], min_depth=0.1, max_depth=5.0)
    for _ in range(3):
        mapper.integrate_arrays(*wall_frame(label=3))
    cloud = m.cloud()
    assert len(cloud) > 0
    top, conf = m.class_at(cloud.centers)
    assert np.array_equal(top, cloud.labels) and np.allclose(conf, cloud.confidence)
    assert np.all(top == 3) and top.dtype == np.uint16 and conf.dtype == np.float32
    # in front of the wall (free space), far away, not finite: no class
    probe = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 900.0], [np.nan, 0.0, 0.0]])
    top, conf = m.class_at(probe)
    assert np.all(top == EMPTY_LABEL) and np.all(conf == 0)
    assert np.array_equal(voxels_of_class(m, 3), cloud.centers)
    assert np.array_equal(voxels_of_class(m, "class_3"), cloud.centers)
    assert len(voxels_of_class(m, 1)) == 0


def test_voxels_of_class_names_a_bad_class():
    m = semmap.SemanticOctoMap(0.05, label_set=LabelSet.generic(5))
    with pytest.raises(ConfigError, match="chair"):
        voxels_of_class(m, "chair")
    with pytest.raises(ConfigError, match="outside"):
        voxels_of_class(m, 7)
    with pytest.raises(ConfigError, match="label set"):
        voxels_of_class(semmap.SemanticOctoMap(0.05), "chair")


def test_integrate_arrays_maps_exactly_what_integrate_maps_from_a_frame():
    labels = LabelSet.generic(5)
    rgb, depth, K, T, ids = wall_frame(label=4)
    T = T.copy()
    T[:3, 3] = [0.1, -0.2, 0.05]
    a, b = semmap.SemanticOctoMap(0.05, label_set=labels), semmap.SemanticOctoMap(0.05, label_set=labels)
    Mapper([a], min_depth=0.1, max_depth=5.0).integrate_arrays(rgb, depth, K, T, ids, label_confidence=0.7)
    frame = semmap.Frame(0, 0.0, rgb, depth, CAM, T_world_cam=T)
    Mapper([b], min_depth=0.1, max_depth=5.0).integrate(frame, T, TopKProbs.from_hard_labels(ids, 0.7, 5, 3))
    ca, cb = a.cells(), b.cells()
    assert np.array_equal(ca.packed, cb.packed) and np.array_equal(ca.sem_labels, cb.sem_labels)
    assert np.array_equal(ca.sem_probs, cb.sem_probs) and np.array_equal(ca.rgb, cb.rgb)


def test_class_probabilities_and_ready_class_sets_are_taken_too():
    labels = LabelSet.generic(4)
    rgb, depth, K, T, _ = wall_frame()
    probs = np.zeros((CAM.height, CAM.width, 4), np.float32)
    probs[..., 2], probs[..., 1] = 0.8, 0.2
    for semantics in (probs, TopKProbs.from_dense(probs, 3)):
        m = semmap.SemanticVoxelGrid(0.05, label_set=labels)
        Mapper([m], min_depth=0.1, max_depth=5.0).integrate_arrays(rgb, depth, K, T, semantics)
        assert np.all(m.cloud().labels == 2)
    m = semmap.SemanticOctoMap(0.05)  # no label set, no classes: geometry and colour only
    Mapper([m], min_depth=0.1, max_depth=5.0).integrate_arrays(rgb, depth, K, T)
    assert m.num_occupied > 0 and np.all(m.cloud().labels == EMPTY_LABEL)


def test_bad_arrays_are_named():
    rgb, depth, K, _, ids = wall_frame()
    with pytest.raises(ConfigError, match="depth"):
        frame_from_arrays(rgb, (depth * 1000).astype(np.uint16), K)
    with pytest.raises(ConfigError, match="colour"):
        frame_from_arrays(rgb[..., 0], depth, K)
    with pytest.raises(ConfigError, match="3x3"):
        frame_from_arrays(rgb, depth, np.eye(4))
    with pytest.raises(ConfigError, match="intrinsics are for"):
        frame_from_arrays(rgb, depth, CameraIntrinsics(32, 24, 50.0, 50.0, 15.5, 11.5))
    shape = depth.shape
    with pytest.raises(ConfigError, match="label set"):
        class_sets(ids, shape, num_classes=None)
    with pytest.raises(ConfigError, match="outside"):
        class_sets(ids + 10, shape, num_classes=5)
    with pytest.raises(ConfigError, match="ids"):
        class_sets(ids - 5, shape, num_classes=5)
    with pytest.raises(ConfigError, match="classes"):
        class_sets(np.ones((*shape, 3), np.float32), shape, num_classes=5)
    with pytest.raises(ConfigError, match="semantics must be"):
        class_sets(ids[:10], shape, num_classes=5)
    bad = depth.copy()
    bad[0, :3] = [np.nan, np.inf, -1.0]
    assert np.all(frame_from_arrays(rgb, bad, K).depth[0, :3] == 0)  # invalid readings become "no depth"


@pytest.mark.parametrize("kind", list(MapKind))
def test_save_map_and_load_map_round_trip_every_kind(kind, tmp_path):
    m = make_map(kind, LabelSet.generic(5))
    Mapper([m], min_depth=0.1, max_depth=5.0).integrate_arrays(*wall_frame(label=1))
    path = tmp_path / "m.semmap"
    assert semmap.save_map(path, m) == path.stat().st_size
    back = semmap.load_map(path)
    assert type(back) is type(m) and back.kind == kind
    a, b = m.cloud(), back.cloud()
    assert np.array_equal(a.centers, b.centers) and np.array_equal(a.labels, b.labels)
    (tmp_path / "x.semmap").write_bytes(b"not a zip")
    with pytest.raises(FormatError):
        semmap.load_map(tmp_path / "x.semmap")


@pytest.mark.slow
def test_the_python_api_example_builds_and_queries_a_map(tmp_path):
    spec = importlib.util.spec_from_file_location("python_api_example", ROOT / "examples" / "python_api.py")
    example = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(example)
    r = example.build_and_query(tmp_path, frames=20)
    assert r["points_integrated"] > 1_000_000 and r["occupied_voxels"] > 5_000
    assert r["floor_voxels"] > 500 and abs(r["floor_height_m"]) < 0.1  # the simulator's floor is at z = 0
    assert r["chair_voxels_in_grid"] > 0
    assert r["probe_classes"] == ["floor", None] and r["probe_confidence"][1] == 0.0
    assert r["grid_agrees_on_floor"] > 0.9 and r["reloaded_map_answers_the_same"]
    assert Path(r["map_file"]).is_file()
