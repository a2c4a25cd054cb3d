"""The semantic voxel grid and point map: every pixel counts, the fusion kernels agree with a naive reference,
float16 storage, free space, keyframes and normals, lossless files, PLY that other tools read."""

from __future__ import annotations

import numpy as np
import plyfile
import pytest

from semmap.errors import FormatError
from semmap.fusion.dense import expand_topk
from semmap.fusion.half import from_half_bits, to_half_bits
from semmap.fusion.rules import FusionParams, FusionRule
from semmap.io.grid_files import load_grid
from semmap.io.map_files import MAP_FILES, save_map_files
from semmap.io.ply import read_ply
from semmap.keys import coords_to_keys, pack_keys
from semmap.maps.point_map import SemanticPointMap
from semmap.maps.semantic_grid import SemanticGrid
from semmap.maps.voxel_grid import SemanticVoxelGrid
from semmap.types import EMPTY_LABEL, LabelSet, Observation, TopKProbs

EMPTY = int(EMPTY_LABEL)


def random_frame(rng, n: int, K: int, *, k: int = 3, extent: float = 0.4) -> Observation:
    """``n`` points in a small box (many per voxel) with random sorted top-k sets over ``K`` classes."""
    pts = rng.uniform(0.0, extent, (n, 3)).astype(np.float32) + np.float32(1.0)
    raw = rng.random((n, K)) + 0.02  # every class above the rules' probability floor (MIN_PROB)
    raw /= raw.sum(1, keepdims=True)
    top = TopKProbs.from_dense(raw, k)
    return Observation(pts, np.zeros(3), rng.integers(0, 255, (n, 3), dtype=np.uint8), top)


def naive_bayes(frames: list[Observation], resolution: float, K: int) -> dict[int, np.ndarray]:
    """Eq. 2 by hand: per voxel, the sum over every point of log p(c|z) (top-k sets expanded), normalised."""
    out: dict[int, np.ndarray] = {}
    for f in frames:
        packed = pack_keys(coords_to_keys(f.points_world, resolution))
        logp = np.log(expand_topk(f.semantics.labels, f.semantics.probs, K))
        for key in np.unique(packed):
            out[int(key)] = out.get(int(key), np.zeros(K)) + logp[packed == key].sum(0)
    return {key: np.exp(h - h.max()) / np.exp(h - h.max()).sum() for key, h in out.items()}


def grid_probs(m: SemanticVoxelGrid) -> dict[int, np.ndarray]:
    a = m.grid.arrays()
    return dict(zip(a.packed.tolist(), m.grid.class_probs(a), strict=True))


@pytest.mark.parametrize("dtype", ["float32", "float16"])
def test_bayes_grid_sums_every_pixel_like_the_naive_reference(dtype):
    rng = np.random.default_rng(1)
    K = 7
    frames = [random_frame(rng, 300, K) for _ in range(3)]
    m = SemanticVoxelGrid(0.1, label_set=LabelSet.generic(K), fusion=FusionParams(FusionRule.BAYES, logodds_clamp=1e4),
                          dtype=dtype)
    for f in frames:
        m.integrate(f)
    got, expected = grid_probs(m), naive_bayes(frames, 0.1, K)
    assert got.keys() == expected.keys() and len(got) > 10
    tol = 2e-2 if dtype == "float16" else 1e-4
    for key, p in expected.items():
        np.testing.assert_allclose(got[key], p, atol=tol)


def test_colour_only_frames_merged_per_voxel_leave_what_the_per_point_path_leaves():
    """A frame with nothing but colour (the dense cloud) is merged per voxel before the table; keeping geometry
    forces the per-point path, which must leave the same table, rows, hits and colour means (exact sums)."""
    rng = np.random.default_rng(7)
    merged = SemanticGrid(0.02, label_set=None)
    per_point = SemanticGrid(0.02, label_set=None, keep_geometry=True)
    for f in range(6):
        pts = rng.uniform(-0.2, 0.2, (3000, 3)).astype(np.float32) + np.float32(f * 0.05)
        pts = np.repeat(pts, rng.integers(1, 4, len(pts)), axis=0)  # runs in one voxel, as image rows give them
        pts[::97] = np.nan  # skipped, as are keys out of range
        pts[5] = 1e7
        cols = None if f == 2 else rng.integers(0, 256, (len(pts), 3), dtype=np.uint8)
        steps = merged.integrate_points(pts, colors=cols)
        per_point.integrate_points(pts, colors=cols)
    assert sorted(steps) == ["fuse", "hash", "keys"]
    a, b = merged.state(), per_point.state()
    assert merged.num_voxels > 10_000 and a["rgb_count"].max() > 3
    for name in ("rgb", "rgb_count", "hits", "table_keys", "table_logodds", "table_rows", "shard_counts",
                 "shard_capacity", "rows_used"):
        assert np.array_equal(a[name], b[name]), name


def test_every_pixel_counts_not_only_the_first():
    K = 5
    pts = np.full((4, 3), 1.02, np.float32)  # four points in one voxel: class 3 first, then class 2 three times
    labels = np.array([[3, EMPTY], [2, EMPTY], [2, EMPTY], [2, EMPTY]], np.uint16)
    probs = np.full((4, 2), 0.0, np.float32)
    probs[:, 0] = 0.8
    obs = Observation(pts, np.zeros(3), np.zeros((4, 3), np.uint8), TopKProbs(labels, probs))
    for rule in FusionRule:
        if rule == FusionRule.TOPK:
            continue  # topk's sets must match the measurement's k: covered by the k = K test
        m = SemanticVoxelGrid(0.1, label_set=LabelSet.generic(K), fusion=FusionParams(rule))
        m.integrate(obs)
        expected = 3 if rule == FusionRule.MAX else 2  # max keeps the first of equally confident labels
        assert m.cloud().labels.tolist() == [expected], rule


def test_topk_grid_with_k_equal_to_K_is_the_bayes_grid():
    rng = np.random.default_rng(2)
    K = 6
    frames = [random_frame(rng, 200, K, k=K) for _ in range(3)]
    grids = {rule: SemanticVoxelGrid(0.1, label_set=LabelSet.generic(K), fusion=FusionParams(
        rule, k=K, max_confidence=1.0, logodds_clamp=1e4)) for rule in (FusionRule.TOPK, FusionRule.BAYES)}
    for f in frames:
        for m in grids.values():
            m.integrate(f)
    topk, bayes = grid_probs(grids[FusionRule.TOPK]), grid_probs(grids[FusionRule.BAYES])
    assert topk.keys() == bayes.keys()
    for key in topk:
        np.testing.assert_allclose(topk[key], bayes[key], atol=1e-4)


def test_a_150_class_label_set_runs_and_float16_halves_the_state():
    rng = np.random.default_rng(3)
    frame = random_frame(rng, 2000, 150, extent=1.0)
    sizes = {}
    for dtype in ("float32", "float16"):
        m = SemanticVoxelGrid(0.05, label_set=LabelSet.generic(150), dtype=dtype)
        m.integrate(frame)
        d = m.describe()
        assert d["voxels"] == len(m.cloud()) > 100
        sizes[dtype] = m.grid.arrays().dense.nbytes / d["voxels"]
    assert sizes == {"float32": 600.0, "float16": 300.0}


def test_free_space_removes_voxels_that_later_rays_pass_through():
    K = 3
    ghost = np.array([[1.0, 0.02, 0.02]], np.float32)  # a spurious hit in front of a wall at 2 m
    wall = np.stack(np.meshgrid([2.02], np.linspace(-0.3, 0.3, 25), np.linspace(-0.3, 0.3, 25)), -1).reshape(-1, 3)
    maps = {fs: SemanticVoxelGrid(0.1, label_set=LabelSet.generic(K), free_space=fs) for fs in (False, True)}
    for m in maps.values():
        m.integrate(Observation(ghost, np.zeros(3), np.zeros((1, 3), np.uint8)))
        for _ in range(3):
            m.integrate(Observation(wall.astype(np.float32), np.zeros(3), np.zeros((len(wall), 3), np.uint8)))
    x = {fs: m.cloud().centers[:, 0] for fs, m in maps.items()}
    assert (x[False] < 1.5).sum() == 1 and (x[True] < 1.5).sum() == 0
    assert (x[True] > 1.9).sum() == (x[False] > 1.9).sum() > 20
    assert maps[True].describe()["free_voxels"] > 0


def test_point_map_integrates_keyframes_only_with_mean_points_and_normals():
    rng = np.random.default_rng(4)
    pts = np.column_stack([np.full(500, 2.0), rng.uniform(0, 0.2, 500), rng.uniform(0, 0.2, 500)]).astype(np.float32)
    normals = np.tile(np.array([-1.0, 0.0, 0.0], np.float32), (500, 1))
    labels = np.full((500, 3), EMPTY, np.uint16)
    labels[:, 0] = 4
    probs = np.zeros((500, 3), np.float32)
    probs[:, 0] = 0.9
    m = SemanticPointMap(label_set=LabelSet.generic(6))
    obs = Observation(pts, np.zeros(3), np.full((500, 3), 200, np.uint8), TopKProbs(labels, probs), normals=normals)
    m.integrate(obs)
    m.integrate(Observation(pts + 0.5, np.zeros(3), obs.colors, obs.semantics, normals=normals, keyframe=False))
    cloud = m.cloud()
    assert m.describe()["keyframes_integrated"] == 1 and np.all(cloud.centers[:, 1] <= 0.21)
    assert len(cloud) == len(np.unique(pack_keys(coords_to_keys(pts, 0.01))))
    assert np.all(cloud.labels == 4) and np.allclose(cloud.normals, [-1, 0, 0]) and np.all(cloud.colors == 200)
    inside = coords_to_keys(cloud.centers, 0.01)
    assert np.array_equal(np.unique(pack_keys(inside)), np.unique(pack_keys(coords_to_keys(pts, 0.01))))


@pytest.mark.parametrize("kind", ["voxelgrid", "points"])
def test_native_files_round_trip_bit_for_bit_and_ply_opens_in_plyfile(kind, tmp_path):
    rng = np.random.default_rng(5)
    K = 8
    if kind == "voxelgrid":
        m = SemanticVoxelGrid(0.05, label_set=LabelSet.generic(K), fusion=FusionParams(FusionRule.TOPK),
                              dtype="float16", free_space=True)
    else:
        m = SemanticPointMap(0.02, label_set=LabelSet.generic(K), fusion=FusionParams(
            FusionRule.BAYES_PRIOR, prior=np.arange(1, K + 1, dtype=float)))
    for _ in range(2):
        f = random_frame(rng, 400, K)
        m.integrate(Observation(f.points_world, f.origin, f.colors, f.semantics,
                                normals=rng.normal(size=(400, 3)).astype(np.float32)))
    sizes = save_map_files(m, tmp_path)
    native, ply_name = MAP_FILES[m.kind]
    back = load_grid(tmp_path / native)
    a, b = m.grid.arrays(), back.grid.arrays()
    for field in a.__dataclass_fields__:
        assert np.array_equal(getattr(a, field), getattr(b, field)), field
    assert back.fusion == m.fusion and back.label_set == m.label_set and back.kind == m.kind
    cloud = m.cloud()
    assert np.array_equal(back.cloud().labels, cloud.labels)
    ply = plyfile.PlyData.read(str(tmp_path / ply_name))
    v = ply["vertex"]
    assert len(v) == len(cloud) and sizes[ply_name] == (tmp_path / ply_name).stat().st_size
    assert np.allclose(v["x"], cloud.centers[:, 0], atol=1e-6) and np.array_equal(v["label"], cloud.labels)
    assert {"red", "green", "blue", "confidence"} <= set(v.data.dtype.names)
    assert ("nx" in v.data.dtype.names) == (kind == "points")
    assert np.array_equal(read_ply(tmp_path / ply_name).labels, cloud.labels)


def test_damaged_grid_and_ply_files_are_clear_errors(tmp_path):
    m = SemanticVoxelGrid(0.1, label_set=LabelSet.generic(4))
    m.integrate(random_frame(np.random.default_rng(6), 100, 4))
    save_map_files(m, tmp_path)
    native, ply_name = MAP_FILES[m.kind]
    data = (tmp_path / native).read_bytes()
    (tmp_path / "cut.semmap").write_bytes(data[: len(data) // 2])
    with pytest.raises(FormatError, match=r"cut\.semmap"):
        load_grid(tmp_path / "cut.semmap")
    ply = (tmp_path / ply_name).read_bytes()
    (tmp_path / "cut.ply").write_bytes(ply[:-7])
    with pytest.raises(FormatError, match="truncated"):
        read_ply(tmp_path / "cut.ply")


def test_numba_half_conversion_matches_numpy_on_every_float16_and_on_ties():
    import numba as nb

    from semmap.fusion.half import float_to_half, half_to_float

    @nb.njit
    def both(bits, values):
        back = np.empty(bits.shape[0], np.float32)
        out = np.empty(values.shape[0], np.uint16)
        for i in range(bits.shape[0]):
            back[i] = half_to_float(bits[i])
        for i in range(values.shape[0]):
            out[i] = float_to_half(values[i])
        return back, out

    bits = np.arange(65536, dtype=np.uint16)
    ref = from_half_bits(bits)
    finite = np.sort(np.unique(ref[np.isfinite(ref)]))
    ties = ((finite[:-1].astype(np.float64) + finite[1:]) / 2).astype(np.float32)  # round half to even
    rng = np.random.default_rng(7)
    values = np.concatenate([finite, ties, (rng.standard_normal(20000) * 10.0 ** rng.integers(-8, 6, 20000)),
                             [65519.0, 65520.0, 1e9, -1e9]]).astype(np.float32)
    back, out = both(bits, values)
    assert np.array_equal(back[np.isfinite(ref)], ref[np.isfinite(ref)]) and np.isnan(back[~np.isfinite(ref) & (
        bits & 0x3FF > 0)]).all()
    with np.errstate(over="ignore"):
        assert np.array_equal(out, to_half_bits(values))
