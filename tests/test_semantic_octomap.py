"""The semantic OctoMap: occupancy identical to OctoMap's, colour, semantics, queries, growth, coarsening."""

from __future__ import annotations

import itertools
import logging

import numpy as np
import pyoctomap
import pytest

from naive import EMPTY, octomap_states
from semmap.errors import ConfigError
from semmap.keys import coords_to_keys, pack_keys, unpack_keys
from semmap.maps.semantic_octomap import FREE, OCCUPIED, UNKNOWN, SemanticOctoMap, logodds
from semmap.types import LabelSet, TopKProbs


def random_scan(rng, n=3000, origin=(0.0, 0.0, 0.0), radius=(0.5, 3.0)):
    """Points on a few random spheres and planes around ``origin`` (noisy, like a depth frame)."""
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    r = rng.choice(np.linspace(*radius, 4), n) + rng.normal(0, 0.01, n)
    return np.asarray(origin) + d * r[:, None]


def semmap_states(m: SemanticOctoMap) -> dict:
    c = m.cells()
    occ = m.is_occupied(c.logodds)
    return {tuple(k): bool(o) for k, o in zip(unpack_keys(c.packed).tolist(), occ, strict=True)}


@pytest.mark.slow
@pytest.mark.parametrize("resolution", [0.05, 0.1])
def test_occupancy_matches_octomap_discretized_insert_cell_for_cell(resolution):
    rng = np.random.default_rng(0)
    m = SemanticOctoMap(resolution)
    tree = pyoctomap.OcTree(resolution)
    for _i in range(4):
        origin = rng.uniform(-0.5, 0.5, 3)
        pts = random_scan(rng, origin=origin)
        m.insert_points(pts, origin)
        tree.insertPointCloud(pts.astype(np.float64), origin.astype(np.float64), discretize=True)
    assert semmap_states(m) == octomap_states(tree, resolution)


def test_max_range_readings_only_clear_space_like_octomap():
    rng = np.random.default_rng(1)
    m = SemanticOctoMap(0.1, max_range=1.5)
    tree = pyoctomap.OcTree(0.1)
    pts = random_scan(rng, n=2000, radius=(0.5, 4.0))
    m.insert_points(pts, np.zeros(3))
    tree.insertPointCloud(pts, np.zeros(3), max_range=1.5, discretize=True)
    assert semmap_states(m) == octomap_states(tree, 0.1)
    far = np.linalg.norm(pts, axis=1) > 1.7
    assert (m.state_at(pts[far]) != OCCUPIED).all()


def test_wide_scans_are_range_limited_with_a_warning_and_still_match_octomap(caplog):
    rng = np.random.default_rng(2)
    m = SemanticOctoMap(0.1, grid_cell_limit=40**3)
    pts = random_scan(rng, n=1500, radius=(0.5, 6.0))
    with caplog.at_level(logging.WARNING, logger="semmap"):
        stats = m.insert_points(pts, np.zeros(3))
    assert stats.range_limited and "is too fine for the range of the scans" in caplog.text
    limit = m.max_range if m.max_range > 0 else None
    assert limit is None  # the map's own setting is untouched
    tree = pyoctomap.OcTree(0.1)
    side = int((40**3) ** (1 / 3)) - 6
    tree.insertPointCloud(pts, np.zeros(3), max_range=side / 2 * 0.1, discretize=True)
    assert semmap_states(m) == octomap_states(tree, 0.1)


def test_free_cells_never_include_this_scans_hits():
    # a wall of points and, behind it, points whose rays cross the wall's cells
    wall = np.array([[x, y, 1.0] for x in np.arange(-0.5, 0.5, 0.01) for y in np.arange(-0.5, 0.5, 0.01)])
    behind = wall * np.array([1.0, 1.0, 2.0])
    m = SemanticOctoMap(0.05)
    m.insert_points(np.vstack([behind, wall]), np.zeros(3))
    assert (m.state_at(wall) == OCCUPIED).all()


def test_log_odds_clamp_exactly_at_octomaps_float32_bounds():
    m = SemanticOctoMap(0.1)
    p = np.array([[1.0, 0.0, 0.0]])
    for _ in range(10):
        m.insert_points(p, np.zeros(3))
    c = m.cells()
    hit = c.logodds[c.logodds > 0]
    free = c.logodds[c.logodds < 0]
    assert hit.tolist() == [np.float32(3.5110307)] and hit.dtype == np.float32
    assert np.all(free == np.float32(-2.000028))
    assert logodds(0.7) == np.float32(0.84729785)


def test_state_queries_and_unknown_space():
    m = SemanticOctoMap(0.1)
    m.insert_points(np.array([[2.0, 0.0, 0.0]]), np.zeros(3))
    states = m.state_at(np.array([[2.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 3.0, 0.0], [1e9, 0, 0]]))
    assert states.tolist() == [OCCUPIED, FREE, UNKNOWN, UNKNOWN]
    assert m.num_occupied == 1 and m.num_free == m.num_leaves - 1


def test_colour_is_the_mean_of_observations():
    m = SemanticOctoMap(0.1)
    p = np.array([[1.02, 0.01, 0.01]])
    for c in ([10, 20, 30], [30, 40, 50], [20, 30, 40], [0, 10, 20]):
        m.insert_points(p, np.zeros(3), colors=np.array([c], np.uint8))
    v = m.voxels()
    assert v.colors.tolist() == [[15, 25, 35]]


def test_voxel_filter_keeps_the_first_point_of_each_cell_for_colour_and_semantics():
    m = SemanticOctoMap(0.1, label_set=LabelSet.generic(5))
    pts = np.array([[1.01, 0.01, 0.01], [1.05, 0.05, 0.05]])
    sem = TopKProbs(np.array([[1, EMPTY, EMPTY], [2, EMPTY, EMPTY]], np.uint16),
                    np.array([[0.8, 0, 0]] * 2, np.float32))
    m.insert_points(pts, np.zeros(3), colors=np.array([[200, 0, 0], [0, 0, 200]], np.uint8), semantics=sem)
    v = m.voxels()
    assert v.colors.tolist() == [[200, 0, 0]] and v.labels[0, 0] == 1


def test_semantics_fuse_over_frames_and_are_queryable():
    m = SemanticOctoMap(0.1, label_set=LabelSet.generic(6))
    p = np.array([[1.0, 0.0, 0.0]])
    seq = [(3, 0.7), (3, 0.6), (5, 0.6), (3, 0.7)]
    for lab, conf in seq:
        m.insert_points(p, np.zeros(3), semantics=TopKProbs(np.array([[lab, EMPTY, EMPTY]], np.uint16),
                                                             np.array([[conf, 0, 0]], np.float32)))
    s = m.semantics_at(p)
    assert s.labels[0, 0] == 3 and s.labels[0, 1] == 5
    assert 0.5 < s.probs[0, 0] < 1.0
    empty = m.semantics_at(np.array([[0.5, 0.0, 0.0]]))  # a free cell has no semantics
    assert empty.labels[0, 0] == EMPTY


def test_class_ids_outside_the_label_set_are_rejected():
    m = SemanticOctoMap(0.1, label_set=LabelSet.generic(4))
    sem = TopKProbs(np.array([[9, EMPTY, EMPTY]], np.uint16), np.array([[0.9, 0, 0]], np.float32))
    with pytest.raises(ConfigError, match="class id 9"):
        m.insert_points(np.array([[1.0, 0, 0]]), np.zeros(3), semantics=sem)


@pytest.mark.parametrize("bad", [np.zeros((3, 2)), np.zeros(3)])
def test_bad_point_arrays_are_rejected(bad):
    with pytest.raises(ConfigError):
        SemanticOctoMap(0.1).insert_points(bad, np.zeros(3))
    with pytest.raises(ConfigError):
        SemanticOctoMap(0.1).insert_points(np.zeros((2, 3)), [np.nan, 0, 0])


def test_non_finite_points_are_ignored():
    m = SemanticOctoMap(0.1)
    m.insert_points(np.array([[np.nan, 0, 0], [1.0, np.inf, 0], [1.0, 0, 0]]), np.zeros(3))
    assert m.num_occupied == 1


@pytest.mark.slow
def test_hash_table_growth_keeps_every_cell():
    rng = np.random.default_rng(4)
    m = SemanticOctoMap(0.02)
    pts_all = []
    for _ in range(6):
        pts = random_scan(rng, n=20000, radius=(0.5, 2.0))
        m.insert_points(pts, np.zeros(3))
        pts_all.append(pts)
    c = m.cells()
    assert c.packed.size == m.num_leaves == np.unique(c.packed).size
    assert (m.state_at(np.vstack(pts_all)) != UNKNOWN).all()
    assert m.memory_bytes / m.num_leaves < 60


def test_coarsen_takes_the_max_occupancy_and_halves_resolution_per_level():
    rng = np.random.default_rng(5)
    m = SemanticOctoMap(0.02, label_set=LabelSet.generic(5))
    pts = random_scan(rng, n=5000)
    lab = rng.integers(1, 5, len(pts)).astype(np.uint16)
    sem = TopKProbs(np.stack([lab, np.full_like(lab, EMPTY), np.full_like(lab, EMPTY)], 1),
                    np.tile(np.array([0.8, 0, 0], np.float32), (len(pts), 1)))
    m.insert_points(pts, np.zeros(3), colors=rng.integers(0, 255, (len(pts), 3), dtype=np.uint8), semantics=sem)
    maps = [m] + [m.coarsen(level) for level in (1, 2, 3)]
    assert [mm.resolution for mm in maps] == pytest.approx([0.02, 0.04, 0.08, 0.16])
    assert all(a.num_leaves > b.num_leaves for a, b in itertools.pairwise(maps))
    # a coarse cell is occupied exactly when one of its fine cells is
    coarse = maps[2]
    fine_occ = m.voxels().keys
    parents = np.unique(pack_keys(((fine_occ - 32768) >> 2) + 32768))
    assert np.array_equal(np.sort(pack_keys(coarse.voxels().keys)), parents)
    # coarsening twice by one level equals coarsening by two levels (occupancy)
    twice = m.coarsen(1).coarsen(1)
    assert np.array_equal(twice.cells().packed, coarse.cells().packed)
    assert np.array_equal(twice.cells().logodds, coarse.cells().logodds)
    # every occupied coarse cell carries a class from its children
    assert (coarse.voxels().labels[:, 0] < 5).all()


def test_coarse_keys_agree_with_octomap_at_the_coarse_resolution():
    rng = np.random.default_rng(6)
    pts = rng.uniform(-3, 3, (2000, 3))
    fine = coords_to_keys(pts, 0.02)
    coarse = ((fine - 32768) >> 3) + 32768
    assert np.array_equal(coarse, coords_to_keys(pts, 0.16)) or np.mean(
        (coarse == coords_to_keys(pts, 0.16)).all(1)) > 0.999


def test_resolution_is_validated():
    with pytest.raises(ConfigError):
        SemanticOctoMap(0.0)
    with pytest.raises(ConfigError):
        SemanticOctoMap(0.05).coarsen(20)


def test_attributes_stay_with_their_cells_when_the_table_grows_during_hits():
    # an origin outside the key range casts no rays, so every new cell arrives as a hit and the
    # table grows while hits are being inserted
    rng = np.random.default_rng(7)
    pts = rng.uniform(-5, 5, (30000, 3))
    colors = rng.integers(0, 250, (len(pts), 3), dtype=np.uint8)
    m = SemanticOctoMap(0.05)
    m.insert_points(pts, [1e6, 0.0, 0.0], colors=colors)
    keys = coords_to_keys(pts, 0.05)
    _, first = np.unique(pack_keys(keys), return_index=True)
    expected = {tuple(k): tuple(c) for k, c in zip(keys[first].tolist(), colors[first].tolist(), strict=True)}
    v = m.voxels()
    got = {tuple(k): tuple(c) for k, c in zip(v.keys.tolist(), v.colors.tolist(), strict=True)}
    assert got == expected


def test_keys_crowding_one_hash_lane_still_all_fit():
    # every key has z % 8 == 0, so all of them compete for one of the eight slot lanes of each group
    rng = np.random.default_rng(8)
    res = 0.05
    kz = 32768 + 8 * rng.integers(-200, 200, 40000)
    pts = np.stack([rng.uniform(-5, 5, 40000), rng.uniform(-5, 5, 40000), (kz - 32768 + 0.5) * res], 1)
    m = SemanticOctoMap(res)
    m.insert_points(pts, [1e6, 0.0, 0.0])  # origin outside the key range: hits only
    assert m.num_occupied == np.unique(pack_keys(coords_to_keys(pts, res))).size
    assert (m.state_at(pts) == OCCUPIED).all()


def _big_scan(rng, n=40000):
    """A dense frame-like scan: enough endpoint and free cells for the many-item (threaded) passes."""
    pts = random_scan(rng, n=n, radius=(0.6, 2.5))
    labels = np.stack([rng.integers(1, 6, n), rng.integers(6, 11, n), np.full(n, EMPTY)], 1).astype(np.uint16)
    probs = np.broadcast_to(np.array([0.6, 0.3, 0.0], np.float32), (n, 3)).copy()
    colors = rng.integers(0, 250, (n, 3), dtype=np.uint8)
    return pts, colors, TopKProbs(labels, probs)


def _octomap_cells(tree) -> tuple[np.ndarray, np.ndarray]:
    """Packed finest-level keys (sorted) and occupied flags of a pyoctomap tree (vectorised, via its .ot)."""
    from semmap.io.octomap_files import decode_octomap

    leaves = decode_octomap(tree.write(), "pyoctomap")
    keys, src = leaves.expand()
    packed = pack_keys(keys)
    order = np.argsort(packed)
    return packed[order], leaves.occupied(tree.getOccupancyThresLog())[src][order]


@pytest.mark.slow
def test_threaded_and_serial_insertion_give_identical_maps(monkeypatch):
    # big scans run the ray, table and attribute passes on all threads; with the threshold out of reach the same
    # scans run serially: every cell, log-odds, colour and class set must come out the same, and match OctoMap
    from semmap.maps import _octree_kernels as kern

    def build(tree=None):
        rng = np.random.default_rng(11)
        m = SemanticOctoMap(0.05, label_set=LabelSet.generic(12), max_range=2.0)
        for _ in range(3):
            origin = rng.uniform(-0.2, 0.2, 3)
            pts, colors, sem = _big_scan(rng)
            stats = m.insert_points(pts, origin, colors=colors, semantics=sem)
            if tree is not None:
                tree.insertPointCloud(pts, origin, max_range=2.0, discretize=True)
        return m, stats

    tree = pyoctomap.OcTree(0.05)
    threaded, stats = build(tree)
    assert stats.hits >= max(kern.RAYS_PARALLEL_MIN, kern.ROWS_PARALLEL_MIN)
    assert stats.free_cells >= kern.CELLS_PARALLEL_MIN
    for name in ("RAYS_PARALLEL_MIN", "CELLS_PARALLEL_MIN", "ROWS_PARALLEL_MIN"):
        monkeypatch.setattr(kern, name, 1 << 40)
    serial, _ = build()
    a, b = threaded.cells(), serial.cells()
    assert np.array_equal(a.packed, b.packed) and np.array_equal(a.logodds, b.logodds)
    va, vb = threaded.voxels(), serial.voxels()
    assert np.array_equal(va.colors, vb.colors) and np.array_equal(va.labels, vb.labels)
    assert np.array_equal(va.probs, vb.probs)
    keys, occupied = _octomap_cells(tree)
    assert np.array_equal(keys, a.packed) and np.array_equal(occupied, threaded.is_occupied(a.logodds))


@pytest.mark.slow
def test_occupancy_only_reference_of_the_benchmark_matches_the_map_cell_for_cell():
    # the benchmark's yardstick must do the same work: same cells, same log-odds as SemanticOctoMap
    import importlib.util
    import sys
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "benchmarks" / "occupancy_reference.py"
    spec = importlib.util.spec_from_file_location("occupancy_reference", path)
    reference = importlib.util.module_from_spec(spec)
    sys.modules.setdefault("occupancy_reference", reference)  # numba's cache finds its kernels by module name
    spec.loader.exec_module(reference)
    rng = np.random.default_rng(12)
    m, ref = SemanticOctoMap(0.05), reference.OccupancyReference(0.05)
    for _ in range(3):
        origin = rng.uniform(-0.5, 0.5, 3)
        pts = random_scan(rng, n=20000, origin=origin)
        m.insert_points(pts, origin)
        ref.insert_points(pts, origin)
    keys, values = ref.cells()
    c = m.cells()
    assert np.array_equal(keys, c.packed) and np.array_equal(values, c.logodds)
