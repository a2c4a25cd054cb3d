"""Memory of the hashed maps: tables start tiny and grow without losing an entry, a small map costs at most 40 bytes
per leaf, and ``memory_bytes`` counts every array a map holds."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from semmap.geometry import backproject_world
from semmap.keys import TREE_MAX_VAL, pack_keys
from semmap.maps import _hashtable as ht
from semmap.maps.semantic_octomap import SemanticOctoMap
from semmap.types import TopKProbs

#: Bytes per leaf a small map may cost (OctoMap's own tree costs 32-34 on the benchmark's 4-frame maps).
SMALL_MAP_BYTES_PER_LEAF = 40


def clustered_keys(seed: int, n: int, spread: int) -> np.ndarray:
    """``n`` unique packed keys in a few dense blobs (full z-groups crowd the lanes of a small table)."""
    rng = np.random.default_rng(seed)
    centres = rng.integers(-spread, spread + 1, (4, 3))
    keys = centres[rng.integers(0, 4, n)] + rng.integers(-spread, spread + 1, (n, 3)) // 3
    return np.unique(pack_keys(keys + TREE_MAX_VAL))


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31), n=st.integers(1, 6000), spread=st.integers(1, 40),
       start=st.sampled_from([ht.GROUP, 2 * ht.GROUP, 3 * ht.GROUP]), batches=st.integers(1, 6))
def test_sharded_table_grown_from_a_tiny_capacity_keeps_every_entry(seed, n, spread, start, batches):
    packed = clustered_keys(seed, n, spread)
    values = np.arange(packed.size, dtype=np.float32) * 0.5
    rows = np.arange(packed.size, dtype=np.int32)
    t = ht.ShardedTable(start)
    assert t.shard_cap == start
    for part in np.array_split(np.arange(packed.size), batches):
        per_shard = np.bincount(ht.shards_of(packed[part]), minlength=ht.N_SHARDS)
        if ((t.counts + per_shard) > t.fill_limit).any():
            t.grow(ht.round_capacity(((t.counts + per_shard) / ht.MAX_LOAD).max()))
        while not ht.insert_all(t.keys, t.logodds, t.attr, t.counts, t.shard_cap, packed[part], values[part],
                                rows[part]):
            t.grow(ht.round_capacity(t.shard_cap * ht.GROWTH))  # a lane overflowed: grow and insert the rest
        t.settle()
    slots = ht.lookup_many(t.keys, t.shard_cap, packed)
    assert (slots >= 0).all() and np.unique(slots).size == packed.size
    assert np.array_equal(t.logodds[slots], values) and np.array_equal(t.attr[slots], rows)
    assert int(t.counts.sum()) == packed.size == t.used().size
    assert t.counts.max() <= ht.MAX_LOAD * t.shard_cap


def test_growth_is_by_the_factor_or_to_the_need_whichever_is_more():
    assert ht.next_capacity(ht.GROUP, 1000) == ht.round_capacity(1000)  # not 8 * 1.5**k from a tiny table
    assert ht.next_capacity(1000, 10) == ht.round_capacity(1000 * ht.GROWTH)


def scans(seed: int, n_scans: int, points: int):
    """Noisy box-room scans from a few origins: world points, origins, colours and top-3 class sets."""
    rng = np.random.default_rng(seed)
    for _ in range(n_scans):
        origin = rng.uniform(-0.5, 0.5, 3)
        d = rng.normal(size=(points, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        t = np.min(np.abs(np.where(d != 0, 2.0 / np.where(d != 0, d, 1), np.inf)), axis=1)
        pts = origin + d * (t * rng.uniform(0.97, 1.0, points))[:, None]
        labels = np.stack([rng.integers(1, 6, points), rng.integers(6, 9, points),
                           np.full(points, 9)], 1).astype(np.uint16)
        probs = np.tile(np.array([0.6, 0.25, 0.1], np.float32), (points, 1))
        yield pts, origin, rng.integers(0, 255, (points, 3), dtype=np.uint8), TopKProbs(labels, probs)


@settings(max_examples=12, deadline=None)
@given(seed=st.integers(0, 2**31), n_scans=st.integers(1, 4), points=st.integers(1, 4000),
       resolution=st.sampled_from([0.05, 0.1, 0.2]))
def test_octomap_grown_from_a_tiny_table_equals_one_that_never_grew(seed, n_scans, points, resolution):
    grown = SemanticOctoMap(resolution)
    assert grown._shard_cap == ht.GROUP
    for pts, origin, colors, sem in scans(seed, n_scans, points):
        grown.insert_points(pts, origin, colors=colors, semantics=sem)
    roomy = SemanticOctoMap(resolution)
    roomy._alloc_table(2 * grown._shard_cap)  # room for every cell from the start: grows only if a lane overflows
    for pts, origin, colors, sem in scans(seed, n_scans, points):
        roomy.insert_points(pts, origin, colors=colors, semantics=sem)
    a, b = grown.cells(), roomy.cells()
    for name in ("packed", "logodds", "attr", "rgb", "rgb_count", "sem_labels", "sem_probs"):
        assert np.array_equal(getattr(a, name), getattr(b, name)), name
    assert grown.num_leaves == roomy.num_leaves > 0


def depth_frames(n: int):
    """``n`` simulator frames as world points, colours, origins and class ids (what Mapper.integrate hands a map)."""
    from semmap.datasets.simulated import SimulatedDataset

    for f in SimulatedDataset.default(frames=n):
        pts, pix = backproject_world(f.depth, f.intrinsics, f.T_world_cam)
        yield pts, f.rgb.reshape(-1, 3)[pix], f.T_world_cam[:3, 3], f.labels.reshape(-1)[pix]


@pytest.fixture(scope="module")
def small_maps() -> dict[float, SemanticOctoMap]:
    """4-frame maps at 5 and 2 cm, as ``bench_octree_vs_octomap.py --quick`` builds them (occupancy, colour, top-3)."""
    frames = list(depth_frames(4))
    out = {}
    for res in (0.05, 0.02):
        m = SemanticOctoMap(res)
        for pts, colors, origin, labels in frames:
            m.insert_points(pts, origin, colors=colors, semantics=TopKProbs.from_hard_labels(labels, 0.8, 30, 3))
        out[res] = m
    return out


@pytest.mark.slow
@pytest.mark.parametrize("resolution", [0.05, 0.02])
def test_a_small_map_costs_at_most_40_bytes_per_leaf(small_maps, resolution):
    m = small_maps[resolution]
    assert m.num_leaves > 10_000
    assert m.memory_bytes / m.num_leaves <= SMALL_MAP_BYTES_PER_LEAF


def test_an_empty_map_holds_a_few_kilobytes():
    assert SemanticOctoMap(0.05).memory_bytes < 16 * 1024


@pytest.mark.parametrize("resolution", [0.05, 0.02])
def test_memory_bytes_counts_every_array_the_map_holds(small_maps, resolution):
    """Everything allocated counts (slack included), except the scan scratch reused between scans."""
    m = small_maps[resolution]
    scratch = {"_grid", "_scratch"}
    held = sum(v.nbytes for k, v in vars(m).items() if isinstance(v, np.ndarray) and k not in scratch)
    assert m.memory_bytes == held
