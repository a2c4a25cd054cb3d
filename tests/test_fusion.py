"""Top-k Bayesian fusion (Algorithm 1): invariants, the reference pseudocode, and plain Bayes."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from naive import EMPTY, as_arrays, as_dict, fuse_reference_posterior
from semmap.fusion.topk_bayes import fuse_topk

LABELS = st.integers(0, 12)


@st.composite
def semantic_sets(draw, min_size=1, max_size=3):
    labels = draw(st.lists(LABELS, min_size=min_size, max_size=max_size, unique=True))
    raw = draw(st.lists(st.floats(0.02, 1.0), min_size=len(labels), max_size=len(labels)))
    total = draw(st.floats(0.3, 0.98))  # leaves some mass for "others"
    scale = total / sum(raw)
    return {lab: r * scale for lab, r in zip(labels, raw, strict=True)}


def fuse(map_set, meas_set, lam=0.9, max_confidence=1.0):
    ml, mp = as_arrays(map_set)
    zl, zp = as_arrays(meas_set)
    out_l, out_p = fuse_topk(ml, mp, zl, zp, lam=lam, max_confidence=max_confidence)
    return out_l[0], out_p[0]


@pytest.mark.slow
@settings(max_examples=300, deadline=None)
@given(semantic_sets(), semantic_sets(), st.floats(0.0, 1.0))
def test_fused_distribution_sums_to_one_and_keeps_sorted_top3(map_set, meas_set, lam):
    labels, probs = fuse(map_set, meas_set, lam)
    used = labels != EMPTY
    assert used.sum() <= 3
    assert np.all(probs[used] > 0) and np.all(probs[~used] == 0)
    assert np.all(np.diff(probs[used]) <= 1e-7), "top-k must be sorted by confidence"
    others = 1.0 - probs.sum()
    assert -1e-5 <= others <= 1.0
    assert len(set(labels[used].tolist())) == used.sum()


@settings(max_examples=300, deadline=None)
@given(semantic_sets(), semantic_sets(), st.floats(0.0, 1.0))
def test_matches_the_papers_pseudocode(map_set, meas_set, lam):
    labels, probs = fuse(map_set, meas_set, lam)
    expected, posterior = fuse_reference_posterior(map_set, meas_set, lam)
    got = as_dict(labels, probs)
    tie_at_cut = len(posterior) > 3 and abs(posterior[2] - posterior[3]) < 1e-6
    assert set(got) == set(expected) or tie_at_cut
    for lab in set(got) & set(expected):
        assert got[lab] == pytest.approx(expected[lab], rel=1e-4, abs=1e-6)


def _tied(d):
    vals = sorted(d.values())
    return any(abs(a - b) < 1e-6 for a, b in itertools.pairwise(vals))


@settings(max_examples=200, deadline=None)
@given(semantic_sets(min_size=3), st.data())
def test_equals_plain_bayes_when_label_sets_match(map_set, data):
    labels = list(map_set)
    raw = data.draw(st.lists(st.floats(0.05, 1.0), min_size=3, max_size=3))
    meas_set = {lab: r / sum(raw) * 0.9 for lab, r in zip(labels, raw, strict=True)}
    got = as_dict(*fuse(map_set, meas_set))
    prod = {lab: map_set[lab] * meas_set[lab] for lab in labels}
    others = (1 - sum(map_set.values())) * (1 - sum(meas_set.values()))
    z = sum(prod.values()) + others
    for lab in labels:
        assert got[lab] == pytest.approx(prod[lab] / z, rel=1e-4)


def test_lambda_moves_mass_out_of_others():
    # map knows {1: .6}; the measurement says {2: .7}: label 2 enters the map with λ·others₁,
    # label 1 enters the measurement with λ·others₂.
    lam = 0.8
    got = as_dict(*fuse({1: 0.6}, {2: 0.7}, lam))
    p1 = 0.6 * lam * 0.3
    p2 = lam * 0.4 * 0.7
    po = (1 - lam) * 0.4 * (1 - lam) * 0.3
    z = p1 + p2 + po
    assert got == pytest.approx({1: p1 / z, 2: p2 / z}, rel=1e-5)
    # with a larger λ, less stays in "others"
    low = 1 - sum(fuse({1: 0.6}, {2: 0.7}, 0.95)[1])
    high = 1 - sum(fuse({1: 0.6}, {2: 0.7}, 0.5)[1])
    assert low < high


def test_first_observation_is_taken_as_is_and_empty_measurement_changes_nothing():
    labels, probs = fuse({}, {4: 0.7, 2: 0.2})
    assert as_dict(labels, probs) == pytest.approx({4: 0.7, 2: 0.2})
    labels, probs = fuse({4: 0.7, 2: 0.2}, {})
    assert as_dict(labels, probs) == pytest.approx({4: 0.7, 2: 0.2})


def test_repeated_evidence_converges_and_is_capped():
    state = {}
    for _ in range(50):
        state = as_dict(*fuse(state, {3: 0.6, 5: 0.2}, max_confidence=0.99))
    assert max(state, key=state.get) == 3
    assert state[3] == pytest.approx(0.99, abs=1e-6)


def test_a_new_class_can_overturn_a_confident_voxel():
    state = {}
    for _ in range(20):
        state = as_dict(*fuse(state, {3: 0.8}, max_confidence=0.99))
    for _ in range(20):
        state = as_dict(*fuse(state, {7: 0.8}, max_confidence=0.99))
    assert max(state, key=state.get) == 7


def test_bad_arguments_raise():
    ml, mp = as_arrays({1: 0.5})
    with pytest.raises(ValueError, match="λ"):
        fuse_topk(ml, mp, ml, mp, lam=1.5)
    with pytest.raises(ValueError, match="shapes"):
        fuse_topk(ml, mp, ml[:2], mp[:2])
