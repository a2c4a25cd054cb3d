"""Fusion as one seam: every rule on every map through ``fusion/dispatch.py``, a rule registered from this file alone,
the OctoMap agreeing with the voxel grid rule by rule, and the native file's round trip per rule."""

from __future__ import annotations

import numba as nb
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from semmap.errors import ConfigError, FormatError
from semmap.fusion import dispatch
from semmap.fusion.registry import RuleEntry, register, rule_entry, rule_names, unregister
from semmap.fusion.rules import FusionParams, FusionRule, fusion_rule
from semmap.io.map_files import save_map_files
from semmap.io.native import load_map, save_map
from semmap.keys import coords_to_keys, pack_keys
from semmap.maps.point_map import SemanticPointMap
from semmap.maps.semantic_octomap import SemanticOctoMap
from semmap.maps.voxel_grid import SemanticVoxelGrid
from semmap.types import EMPTY_LABEL, LabelSet, Observation, TopKProbs

EMPTY = int(EMPTY_LABEL)
K = 5
RES = 0.1
LABELS = LabelSet.generic(K)


# ------------------------------------------------------------------ a rule defined and registered here alone
@nb.njit
def last_update(labels, values, meas_labels, meas_probs, params):
    """The voxel keeps its latest measurement's top class and probability ("last measurement wins")."""
    if meas_labels[0] == EMPTY:
        return False
    labels[0] = meas_labels[0]
    values[0] = meas_probs[0]
    return True


@pytest.fixture
def last_rule():
    register(RuleEntry("last", "the latest measurement's top class", "set", last_update))
    yield FusionParams("last")
    unregister("last")


def wall(n_side: int = 6) -> np.ndarray:
    """One point at the centre of each voxel of a (n_side x n_side) wall 2 m in front of the origin."""
    ij = np.stack(np.meshgrid(np.arange(n_side), np.arange(n_side), indexing="ij"), -1).reshape(-1, 2)
    return np.column_stack([(ij + 0.5) * RES, np.full(len(ij), 2.0 + 0.5 * RES)])


def sets(labels: np.ndarray, probs: np.ndarray, k: int = 3) -> TopKProbs:
    """(n,) top classes with probabilities -> (n, k) sets whose second class takes half of the rest."""
    n = len(labels)
    out_l = np.full((n, k), EMPTY, np.uint16)
    out_p = np.zeros((n, k), np.float32)
    out_l[:, 0], out_p[:, 0] = labels, probs
    if k > 1:
        out_l[:, 1] = (labels + 1) % K
        out_p[:, 1] = (1.0 - probs) / 2
    return TopKProbs(out_l, out_p)


def maps_for(fusion: FusionParams) -> dict:
    return {"octomap": SemanticOctoMap(RES, label_set=LABELS, fusion=fusion),
            "voxelgrid": SemanticVoxelGrid(RES, label_set=LABELS, fusion=fusion, dtype="float32"),
            "points": SemanticPointMap(RES, label_set=LABELS, fusion=fusion, dtype="float32")}


def integrate(m, pts: np.ndarray, sem: TopKProbs) -> None:
    colors = np.full((len(pts), 3), 100, np.uint8)
    m.integrate(Observation(pts, np.zeros(3), colors, sem, normals=np.tile([0.0, 0.0, -1.0], (len(pts), 1))))


def top_by_key(m) -> dict[int, int]:
    """Top class of each occupied voxel by packed key."""
    c = m.cloud()
    keys = pack_keys(coords_to_keys(c.centers, RES))
    return dict(zip(keys.tolist(), c.labels.tolist(), strict=True))


def test_a_rule_registered_from_a_test_file_runs_on_the_octomap_the_voxel_grid_and_the_point_map(last_rule):
    pts = wall()
    rng = np.random.default_rng(0)
    first = rng.integers(0, K, len(pts))
    last = (first + rng.integers(1, K, len(pts))) % K  # every voxel changes class
    keys = pack_keys(coords_to_keys(pts, RES)).tolist()
    for name, m in maps_for(last_rule).items():
        integrate(m, pts, sets(first, np.full(len(pts), 0.9, np.float32)))
        integrate(m, pts, sets(last, np.full(len(pts), 0.4, np.float32)))  # less confident, and still wins
        got = top_by_key(m)
        assert [got[k] for k in keys] == last.tolist(), name
        assert np.allclose(m.cloud().confidence, 0.4), name
    assert "last" in rule_names() and fusion_rule("last") == "last"


def test_the_registered_rule_round_trips_through_the_native_file_and_coarsens(last_rule, tmp_path):
    m = maps_for(last_rule)["octomap"]
    pts = wall()
    integrate(m, pts, sets(np.arange(len(pts)) % K, np.full(len(pts), 0.6, np.float32)))
    save_map(tmp_path / "m.semmap", m)
    back = load_map(tmp_path / "m.semmap")
    assert back.fusion.name == "last" and back._entry.name == "last"
    a, b = m.cells(), back.cells()
    for name in a.__dataclass_fields__:
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    parent = m.coarsen(1)
    assert parent.cloud().labels.max() < K and len(parent.cloud()) > 0


def test_registering_checks_names_and_layouts():
    with pytest.raises(ConfigError, match="already registered"):
        register(RuleEntry("topk", "again", "set", last_update))
    with pytest.raises(ConfigError, match="layout"):
        register(RuleEntry("odd", "bad layout", "tree", last_update))
    with pytest.raises(ConfigError, match="unknown fusion rule 'nope'"):
        FusionParams("nope")
    with pytest.raises(ConfigError, match="built-in"):
        unregister("bayes")
    assert set(rule_names()) >= {r.value for r in FusionRule}
    assert rule_entry(FusionRule.VOTE).dense and not rule_entry("max").dense


# ------------------------------------------------------------------ built-in rules: OctoMap = voxel grid
RULES = [FusionParams(FusionRule.TOPK), FusionParams(FusionRule.MAX), FusionParams(FusionRule.BAYES),
         FusionParams(FusionRule.BAYES_PRIOR, prior=np.array([5.0, 1.0, 1.0, 2.0, 1.0])),
         FusionParams(FusionRule.VOTE, vote_cap=4.0)]


def states_by_key(m) -> dict[int, tuple]:
    """Each observed voxel's fusion state (labels, values) by packed key, whatever the map."""
    if isinstance(m, SemanticOctoMap):
        c = m.cells()
        has = c.attr >= 0
        rows = c.attr[has]
        return {int(k): (c.sem_labels[r].tolist(), c.sem_probs[r].tolist()) for k, r in zip(c.packed[has], rows,
                                                                                            strict=True)}
    a = m.grid.arrays()
    values = a.dense if a.dense.shape[1] else a.set_probs
    return {int(k): (a.set_labels[i].tolist(), values[i].tolist()) for i, k in enumerate(a.packed)}


@pytest.mark.slow
@settings(max_examples=8, deadline=None)
@given(st.integers(0, 2**31 - 1), st.integers(1, 6))
def test_every_rule_on_the_octomap_equals_the_same_rule_on_the_voxel_grid(seed, frames):
    """One point per voxel per frame: the OctoMap's first point of a cell and the grid's every point are the same
    measurement, so the states must agree bit for bit, rule by rule."""
    rng = np.random.default_rng(seed)
    pts = wall(5)
    for fusion in RULES:
        octo = SemanticOctoMap(RES, label_set=LABELS, fusion=fusion)
        grid = SemanticVoxelGrid(RES, label_set=LABELS, fusion=fusion, dtype="float32")
        for _ in range(frames):
            sem = sets(rng.integers(0, K, len(pts)), rng.uniform(0.3, 0.95, len(pts)).astype(np.float32))
            integrate(octo, pts, sem)
            integrate(grid, pts, sem)
        assert states_by_key(octo) == states_by_key(grid), fusion.name
        np.testing.assert_array_equal(octo.cloud().labels, grid.cloud().labels)


@pytest.mark.parametrize("fusion", RULES, ids=lambda f: f.name)
def test_every_rule_on_the_octomap_writes_reads_coarsens_and_refines(fusion, tmp_path):
    m = SemanticOctoMap(RES, label_set=LABELS, fusion=fusion)
    pts = wall()
    rng = np.random.default_rng(1)
    for _ in range(3):
        integrate(m, pts, sets(rng.integers(1, K, len(pts)), rng.uniform(0.4, 0.9, len(pts)).astype(np.float32)))
    sizes = save_map_files(m, tmp_path)
    assert sizes["map.ot"] > 0 and sizes["map.bt"] > 0
    back = load_map(tmp_path / "map.semmap")
    assert back.fusion == fusion
    a, b = m.cells(), back.cells()
    for name in a.__dataclass_fields__:
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    cloud = m.cloud()
    assert len(cloud) == len(pts) and (cloud.labels < K).all() and (cloud.confidence > 0).all()
    probs = m.class_probs()
    assert probs.shape == (len(pts), K) and np.allclose(probs.sum(1), 1.0, atol=1e-5)
    np.testing.assert_array_equal(probs.argmax(1), cloud.labels)
    assert m.semantics_at(cloud.centers).labels[:, 0].tolist() == cloud.labels.tolist()
    target = np.eye(K, dtype=np.float32)[np.full(len(pts), 2)] * 0.9 + 0.02
    m.set_class_probs(target)
    assert (m.cloud().labels == 2).all()
    d = m.describe()
    assert d["occupied_voxels"] == len(pts) and d["occupied_leaves"] > 0
    coarse = m.coarsen(2)
    assert (coarse.cloud().labels == 2).all() and len(coarse.cloud()) < len(pts)


def test_the_generic_path_gives_what_the_fast_path_gives():
    """A built-in rule registered again without its fast path (its kernels called as function values) fuses the
    same, on the OctoMap and on the voxel grid."""
    rng = np.random.default_rng(3)
    pts = wall(4)
    frames = [sets(rng.integers(0, K, len(pts)), rng.uniform(0.3, 0.9, len(pts)).astype(np.float32))
              for _ in range(4)]
    for name in ("topk", "max", "bayes-prior", "vote"):
        e = rule_entry(name)
        register(RuleEntry(f"{name}-generic", e.help, e.layout, e.update, e.finish, e.set_width, e.sets_of_k))
        try:
            prior = np.array([5.0, 1.0, 1.0, 2.0, 1.0])
            fast = FusionParams(name, prior=prior, vote_cap=4.0)
            slow = FusionParams(f"{name}-generic", prior=prior, vote_cap=4.0)
            for make in (lambda f: SemanticOctoMap(RES, label_set=LABELS, fusion=f),
                         lambda f: SemanticVoxelGrid(RES, label_set=LABELS, fusion=f, dtype="float32")):
                a, b = make(fast), make(slow)
                for sem in frames:
                    integrate(a, pts, sem)
                    integrate(b, pts, sem)
                assert states_by_key(a) == states_by_key(b), name
        finally:
            unregister(f"{name}-generic")


def test_the_default_native_header_keeps_the_version_1_topk_form(tmp_path):
    import json
    import zipfile

    m = SemanticOctoMap(RES, label_set=LABELS)
    integrate(m, wall(3), sets(np.ones(9, np.int64), np.full(9, 0.7, np.float32)))
    save_map(tmp_path / "m.semmap", m)
    with zipfile.ZipFile(tmp_path / "m.semmap") as z:
        header = json.loads(np.load(z.open("header.npy")).tobytes())
    assert header["version"] == 1 and header["semantics"] == {"k": 3, "lam": 0.9, "max_confidence": 0.999}
    assert load_map(tmp_path / "m.semmap").fusion == FusionParams()


def test_a_native_file_of_an_unknown_rule_is_a_clear_error(last_rule, tmp_path):
    m = SemanticOctoMap(RES, label_set=LABELS, fusion=last_rule)
    integrate(m, wall(3), sets(np.ones(9, np.int64), np.full(9, 0.7, np.float32)))
    save_map(tmp_path / "m.semmap", m)
    unregister("last")
    with pytest.raises(FormatError, match="unknown fusion rule 'last'"):
        load_map(tmp_path / "m.semmap")
    register(RuleEntry("last", "again", "set", last_update))  # the fixture removes it


def test_full_k_rules_need_a_label_set_and_the_scratch_size_is_defined_once():
    with pytest.raises(ConfigError, match="label set"):
        SemanticOctoMap(RES, fusion=FusionParams(FusionRule.BAYES))
    si, sf = dispatch.new_scratch()
    assert si.shape == sf.shape == (3, dispatch.SCRATCH)
