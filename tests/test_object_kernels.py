"""The object map's numba kernels agree with the numpy operations they replace (sorted-key set algebra, the
per-cell merge of an object's cloud, cells per detection) and the tracker's colour histograms with a bincount."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from semmap.maps._object_kernels import (
    cells_per_segment,
    merge_cells,
    segment_bounds_and_mean,
    sorted_intersection_size,
    sorted_union,
)
from semmap.maps.objects import _KEY_BITS, pack_cells
from semmap.perception.tracking.appearance import BINS_PER_CHANNEL, PIXEL_STRIDE, colour_histograms

keys = st.lists(st.integers(-(2**40), 2**40), max_size=60).map(lambda v: np.unique(np.array(v, np.int64)))


@settings(max_examples=200, deadline=None)
@given(keys, keys)
def test_sorted_set_algebra_matches_numpy(a: np.ndarray, b: np.ndarray) -> None:
    assert sorted_intersection_size(a, b) == len(np.intersect1d(a, b))
    np.testing.assert_array_equal(sorted_union(a, b), np.union1d(a, b))


@settings(max_examples=200, deadline=None)
@given(keys, keys, st.integers(0, 2**31))
def test_merge_keeps_existing_cells_and_inserts_new_ones_in_order(old: np.ndarray, new: np.ndarray,
                                                                  seed: int) -> None:
    rng = np.random.default_rng(seed)
    pts_old = rng.normal(size=(len(old), 3)).astype(np.float32)
    pts_new = rng.normal(size=(len(new), 3)).astype(np.float32)
    col_old = rng.integers(0, 256, (len(old), 3), dtype=np.uint8)
    col_new = rng.integers(0, 256, (len(new), 3), dtype=np.uint8)
    k, p, c, added = merge_cells(old, pts_old, col_old, new, pts_new, col_new)
    np.testing.assert_array_equal(k, np.union1d(old, new))
    fresh = ~np.isin(new, old)
    expect_p = dict(zip(old.tolist(), pts_old.tolist(), strict=True)) | \
        dict(zip(new[fresh].tolist(), pts_new[fresh].tolist(), strict=True))
    expect_c = dict(zip(old.tolist(), col_old.tolist(), strict=True)) | \
        dict(zip(new[fresh].tolist(), col_new[fresh].tolist(), strict=True))
    assert p.tolist() == [expect_p[x] for x in k.tolist()]  # a cell the object had keeps its point
    assert c.tolist() == [expect_c[x] for x in k.tolist()]
    np.testing.assert_allclose(added, pts_new[fresh].sum(axis=0, dtype=np.float64), atol=1e-9)


@settings(max_examples=100, deadline=None)
@given(st.lists(st.integers(0, 40), min_size=1, max_size=6), st.integers(0, 2**31), st.sampled_from([0.01, 0.03, 0.1]))
def test_cells_per_segment_are_each_segments_unique_packed_cells(sizes: list[int], seed: int, cell: float) -> None:
    rng = np.random.default_rng(seed)
    points = rng.uniform(-3, 3, (sum(sizes), 3))
    bounds = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
    got, got_bounds, ok = cells_per_segment(points, bounds, cell, _KEY_BITS)
    assert ok
    mean, lo, hi = segment_bounds_and_mean(points, bounds)
    for k in range(len(sizes)):
        seg = points[bounds[k]:bounds[k + 1]]
        expect = np.unique(pack_cells(np.floor(seg / cell).astype(np.int64)))
        np.testing.assert_array_equal(got[got_bounds[k]:got_bounds[k + 1]], expect)
        if len(seg):
            np.testing.assert_allclose(mean[k], seg.mean(axis=0), atol=1e-12)
            np.testing.assert_array_equal(lo[k], seg.min(axis=0))
            np.testing.assert_array_equal(hi[k], seg.max(axis=0))


def test_colour_histograms_count_each_masks_quantised_colours() -> None:
    rng = np.random.default_rng(3)
    rgb = rng.integers(0, 256, (61, 83, 3), dtype=np.uint8)
    ids = rng.integers(0, 5, (61, 83)).astype(np.int32)
    hist = colour_histograms(rgb, ids, 4)
    q = (rgb[::PIXEL_STRIDE, ::PIXEL_STRIDE].astype(np.int64) * BINS_PER_CHANNEL) // 256
    bin_of = (q[..., 0] * BINS_PER_CHANNEL + q[..., 1]) * BINS_PER_CHANNEL + q[..., 2]
    sub = ids[::PIXEL_STRIDE, ::PIXEL_STRIDE]
    for k in range(1, 5):
        counts = np.bincount(bin_of[sub == k], minlength=BINS_PER_CHANNEL**3).astype(np.float64)
        expect = np.sqrt(counts) / np.linalg.norm(np.sqrt(counts))
        np.testing.assert_allclose(hist[k - 1], expect, atol=1e-6)
    assert colour_histograms(rgb, ids, 0).shape == (0, BINS_PER_CHANNEL**3)


def test_cells_out_of_the_key_range_are_reported() -> None:
    points = np.array([[0.0, 0.0, 0.0], [2e4, 0.0, 0.0]])  # 2 million 1 cm cells from the origin
    assert not cells_per_segment(points, np.array([0, 2]), 0.01, _KEY_BITS)[2]
    assert cells_per_segment(points, np.array([0, 2]), 0.1, _KEY_BITS)[2]
