"""semmap merge (issue 36, deliverable 2): two halves of one simulated recording, mapped apart and merged, equal the
map of the whole recording; the alignment is given or estimated (and refused without overlap); incompatible maps
are refused in one line."""

from __future__ import annotations

import json

import numpy as np
import pytest
from typer.testing import CliRunner

from semmap.cli import app
from semmap.errors import ConfigError, FormatError
from semmap.io.map_files import load_map, save_map
from semmap.maps.semantic_octomap import SemanticOctoMap
from semmap.maps.voxel_grid import SemanticVoxelGrid
from semmap.products.merge import estimate_alignment, merge_maps, read_transform
from semmap.products.occupancy import OCCUPIED, UNKNOWN, map_keys, volume_of_keys
from semmap.types import CameraIntrinsics

RES = 0.1
CAMERA = CameraIntrinsics(160, 120, 131.25, 131.25, 79.5, 59.5)
FRAMES = 24


@pytest.fixture(scope="module")
def recording():
    """A small simulated office, a loop of FRAMES frames, their oracle class sets."""
    from semmap.datasets.simulated import SimulatedDataset
    from semmap.perception.oracle import OracleSegmenter
    from semmap.sim.scene import generate_scene
    from semmap.sim.trajectory import make_trajectory

    scene = generate_scene(0, "office", "small")
    ds = SimulatedDataset(scene, make_trajectory(scene, "loop", FRAMES, seed=0), intrinsics=CAMERA)
    frames = list(ds)
    seg = OracleSegmenter(ds.label_set)
    return ds.label_set, frames, [seg.segment(f) for f in frames]


_BUILT: dict = {}


def build(recording, kind: str, part: slice):
    """The map of ``kind`` of the frames ``part`` (built once per module: merging never changes its inputs)."""
    key = (kind, part.start, part.stop)
    if key not in _BUILT:
        _BUILT[key] = _build(recording, kind, part)
    return _BUILT[key]


def _build(recording, kind: str, part: slice):
    from semmap.pipeline import Mapper

    labels, frames, sems = recording
    if kind == "points":
        from semmap.maps.point_map import SemanticPointMap

        m = SemanticPointMap(RES / 2, label_set=labels, keyframes_only=False)  # float16 bayes-prior state
    else:
        m = (SemanticOctoMap(RES, label_set=labels) if kind == "octomap"
             else SemanticVoxelGrid(RES, label_set=labels, free_space=True))
    mapper = Mapper([m], min_depth=0.1, max_depth=6.0)
    for f, s in zip(frames[part], sems[part], strict=True):
        mapper.integrate(f, f.T_world_cam, s)
    return m


def agreement(x, y) -> tuple[float, float]:
    """Share of the cells either map knows (and of those either holds occupied) where both agree: the same
    occupied state and, where occupied, the same class."""
    kx, ky = map_keys(x), map_keys(y)
    every = np.concatenate([k for occ, _, free in (kx, ky) for k in (occ, free)])
    lo, hi = every.min(0), every.max(0)
    vx, vy = (volume_of_keys(k, x.resolution, lo, hi, None) for k in (kx, ky))
    ox, oy = vx.state == OCCUPIED, vy.state == OCCUPIED
    same = (ox == oy) & (~(ox & oy) | (vx.labels == vy.labels))
    known = (vx.state != UNKNOWN) | (vy.state != UNKNOWN)
    return float(same[known].mean()), float(same[ox | oy].mean())


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["octomap", "voxelgrid"])
def test_two_halves_merged_equal_the_whole_recording(recording, kind):
    half = FRAMES // 2
    whole = build(recording, kind, slice(None))
    a, b = build(recording, kind, slice(0, half)), build(recording, kind, slice(half, None))
    cells, occupied = agreement(whole, merge_maps(a, b))
    print(f"{kind}: merged = whole in {100 * cells:.2f} % of known cells, {100 * occupied:.2f} % of occupied")
    assert cells >= 0.99 and occupied >= 0.98
    assert agreement(whole, a)[1] < 0.8  # one half alone is far from the whole: the test can fail
    alignment = estimate_alignment(a, b)  # the halves share a frame: the estimate must find it
    assert np.abs(alignment.transform[:3, 3]).max() < RES / 2 and alignment.overlap > 0.5
    assert agreement(whole, merge_maps(a, b, alignment.transform))[0] >= 0.99


@pytest.mark.slow
def test_point_maps_merge_too(recording):
    half = FRAMES // 2
    whole = build(recording, "points", slice(None))
    a, b = build(recording, "points", slice(0, half)), build(recording, "points", slice(half, None))
    merged = merge_maps(a, b)
    assert agreement(whole, merged)[1] >= 0.98
    assert merged.frames_integrated == whole.frames_integrated
    assert np.abs(merged.cloud().centers - whole.cloud().centers).max() < 1e-3  # mean positions, hit-weighted


def _turned(m: SemanticOctoMap, T: np.ndarray) -> SemanticOctoMap:
    """``m`` moved by ``T`` (resampled on its lattice): a second session's map in its own frame."""
    return merge_maps(SemanticOctoMap(m.resolution, label_set=m.label_set, fusion=m.fusion), m, T)


@pytest.mark.parametrize("degrees, shift", [(25, (0.6, -0.4, 0.1)), (200, (-1.0, 2.0, 0.2))])
def test_an_estimated_alignment_undoes_a_turn_and_a_shift(recording, degrees, shift):
    a = build(recording, "octomap", slice(0, FRAMES // 2))
    b = build(recording, "octomap", slice(FRAMES // 2, None))
    c, s = np.cos(np.radians(degrees)), np.sin(np.radians(degrees))
    T = np.array([[c, -s, 0, shift[0]], [s, c, 0, shift[1]], [0, 0, 1, shift[2]], [0, 0, 0, 1]])
    found = estimate_alignment(a, _turned(b, T)).transform @ T  # the identity, if found
    angle = np.degrees(np.arccos(np.clip((np.trace(found[:3, :3]) - 1) / 2, -1, 1)))
    print(f"turned {degrees} deg: error {100 * np.linalg.norm(found[:3, 3]):.2f} cm, {angle:.2f} deg")
    assert np.linalg.norm(found[:3, 3]) < RES and angle < 3.0  # within a voxel of the truth (10 cm voxels)


def test_maps_of_different_places_are_refused(recording):
    a = build(recording, "octomap", slice(0, FRAMES // 2))
    rng = np.random.default_rng(0)
    clutter = SemanticOctoMap(RES, label_set=a.label_set)  # scattered voxels: a place unlike any room
    points = rng.uniform([-2, -2, 0], [2, 2, 2.5], (400, 3))
    clutter.insert_points(points, np.array([0.0, 0.0, 1.2]))
    with pytest.raises(ConfigError, match="do not overlap enough") as err:
        estimate_alignment(a, clutter, min_overlap=0.3)
    assert "\n" not in str(err.value) and "--transform" in str(err.value)


def test_incompatible_maps_are_refused_in_one_line(recording):
    labels = recording[0]
    o = SemanticOctoMap(RES, label_set=labels)
    for other, what in ((SemanticOctoMap(0.05, label_set=labels), "resolution"),
                        (SemanticVoxelGrid(RES, label_set=labels), "map kind"),
                        (SemanticOctoMap(RES, label_set=None), "label set")):
        with pytest.raises(ConfigError, match=what) as err:
            merge_maps(o, other)
        assert "\n" not in str(err.value)


def test_transform_files(tmp_path):
    good = tmp_path / "t.txt"
    good.write_text("# T_A_B\n0 -1 0 1\n1 0 0 2\n0 0 1 3\n0 0 0 1\n")
    assert read_transform(good)[:3, 3].tolist() == [1, 2, 3]
    for text in ("1 0 0\n0 1 0\n0 0 1\n", "2 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n", "a b c d\n" * 4):
        good.write_text(text)
        with pytest.raises(FormatError):
            read_transform(good)


def test_merge_command_writes_the_map_and_refuses_its_inputs(recording, tmp_path):
    a = build(recording, "octomap", slice(0, FRAMES // 2))
    b = build(recording, "octomap", slice(FRAMES // 2, None))
    save_map(tmp_path / "a.semmap", a)
    save_map(tmp_path / "b.semmap", b)
    eye = tmp_path / "eye.txt"
    eye.write_text("1 0 0 0\n0 1 0 0\n0 0 1 0\n0 0 0 1\n")
    out = tmp_path / "merged"
    r = CliRunner().invoke(app, ["merge", str(tmp_path / "a.semmap"), str(tmp_path / "b.semmap"), "--out", str(out),
                                 "--transform", str(eye), "--json"])
    assert r.exit_code == 0, r.output
    s = json.loads(r.output)
    assert s["alignment"]["source"] == "given" and s["occupied"]["merged"] > max(s["occupied"]["a"],
                                                                                  s["occupied"]["b"])
    assert {p.name for p in out.iterdir()} >= {"map.ot", "map.bt", "map.semmap", "merge.json", "transform.txt"}
    assert len(map_keys(load_map(out / "map.semmap"))[0]) == s["occupied"]["merged"]
    r = CliRunner().invoke(app, ["merge", str(tmp_path / "a.semmap"), str(tmp_path / "b.semmap"), "--out",
                                 str(tmp_path / "a.semmap")])
    assert r.exit_code != 0 and "input" in str(r.exception or r.output)
