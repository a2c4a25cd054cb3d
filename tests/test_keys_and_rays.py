"""OctoMap-exact keys and ray traversal, checked against the real OctoMap library (pyoctomap)."""

from __future__ import annotations

import numpy as np
import pyoctomap
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from semmap.keys import coords_to_keys, keys_to_coords, pack_keys, unpack_keys
from semmap.maps._keys import ray_keys


@pytest.mark.parametrize("resolution", [0.02, 0.05, 0.1, 0.16])
def test_keys_match_octomap_coord_to_key(resolution):
    rng = np.random.default_rng(1)
    pts = rng.uniform(-30, 30, (300, 3)).astype(np.float32)
    pts[:50] = (np.round(pts[:50] / resolution) * resolution).astype(np.float32)  # on cell borders
    tree = pyoctomap.OcTree(resolution)
    ours = coords_to_keys(pts, resolution)
    for p, k in zip(pts.astype(np.float64), ours, strict=True):
        ref = tree.coordToKey(p)
        assert (ref[0], ref[1], ref[2]) == tuple(k)


def test_key_centres_round_trip_and_packing():
    rng = np.random.default_rng(2)
    keys = rng.integers(0, 65536, (500, 3))
    assert np.array_equal(unpack_keys(pack_keys(keys)), keys)
    assert np.array_equal(coords_to_keys(keys_to_coords(keys, 0.05), 0.05), keys)


def _octomap_ray_free_cells(origin, end, resolution):
    """Free cells OctoMap marks for one ray (computeRayKeys without the end cell), via insertPointCloud."""
    tree = pyoctomap.OcTree(resolution)
    tree.insertPointCloud(np.array([end], np.float64), np.array(origin, np.float64), discretize=False)
    free = set()
    for leaf in tree.begin_leafs():
        if not tree.isNodeOccupied(leaf):
            assert leaf.getSize() == pytest.approx(resolution)
            free.add(tuple(coords_to_keys(np.array([leaf.getCoordinate()]), resolution)[0]))
    return free


@pytest.mark.slow
def test_ray_cells_match_octomap_compute_ray_keys_on_random_rays():
    rng = np.random.default_rng(3)
    for i in range(150):
        res = (0.02, 0.05, 0.1)[i % 3]
        o = rng.uniform(-2, 2, 3).astype(np.float32)
        e = (o + rng.normal(0, 1.5, 3)).astype(np.float32)
        if i % 5 == 0:
            e[i % 3] = o[i % 3]  # axis-parallel component
        if i % 7 == 0:
            e = (np.round(e / res) * res).astype(np.float32)  # ends on cell borders
        ours = {tuple(k) for k in ray_keys(o, e, res).tolist()}
        ours.discard(tuple(coords_to_keys(e[None], res)[0]))
        assert ours == _octomap_ray_free_cells(o, e, res), f"ray {i}: {o} -> {e} at {res}"


@pytest.mark.slow
@settings(max_examples=200, deadline=None)
@given(st.lists(st.floats(-5, 5, width=32), min_size=6, max_size=6), st.sampled_from([0.02, 0.05, 0.2]))
def test_ray_is_a_connected_walk_from_the_origin_cell_that_never_enters_the_end_cell(coords, res):
    o = np.array(coords[:3], np.float32)
    e = np.array(coords[3:], np.float32)
    keys = ray_keys(o, e, res)
    ko, ke = coords_to_keys(o[None], res)[0], coords_to_keys(e[None], res)[0]
    if np.array_equal(ko, ke):
        assert len(keys) == 0
        return
    assert np.array_equal(keys[0], ko)
    steps = np.abs(np.diff(keys, axis=0)).sum(axis=1)
    assert np.all(steps == 1), "consecutive ray cells are face neighbours"
    assert not (keys == ke).all(axis=1).any()
    # at most one extra step per axis: an end exactly on a cell border may be passed by float rounding,
    # exactly as in OctoMap
    assert len(keys) <= np.abs(ke - ko).sum() + 3
    lo, hi = np.minimum(ko, ke) - 1, np.maximum(ko, ke) + 1
    assert ((keys >= lo) & (keys <= hi)).all()
