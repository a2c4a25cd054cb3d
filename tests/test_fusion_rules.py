"""The fusion rules besides top-k (max, bayes, bayes-prior, vote): invariants, references, and top-k = Bayes."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from semmap.errors import ConfigError
from semmap.fusion.dense import MIN_PROB, expand_topk, fuse_bayes, fuse_vote, logodds_to_probs
from semmap.fusion.max_rule import fuse_max
from semmap.fusion.rules import FusionParams, FusionRule, fusion_rule
from semmap.fusion.topk_bayes import fuse_topk
from semmap.types import EMPTY_LABEL

EMPTY = int(EMPTY_LABEL)
BIG_CLAMP = 1e4  # no clamping: pure Bayes


@st.composite
def topk_sets(draw, num_classes: int, k: int = 3):
    """One top-k measurement over ``num_classes`` classes, sorted, with some mass left to "others"."""
    n = draw(st.integers(1, min(k, num_classes)))
    labels = draw(st.lists(st.integers(0, num_classes - 1), min_size=n, max_size=n, unique=True))
    raw = draw(st.lists(st.floats(0.05, 1.0), min_size=n, max_size=n))
    total = draw(st.floats(0.3, 0.97))
    p = np.sort(np.array(raw) / sum(raw) * total)[::-1]
    out_l = np.full(k, EMPTY, np.uint16)
    out_p = np.zeros(k, np.float32)
    out_l[:n], out_p[:n] = labels, p
    return out_l, out_p


@st.composite
def measurement_sequences(draw, num_classes: int, k: int = 3, max_len: int = 6):
    m = draw(st.integers(1, max_len))
    sets = [draw(topk_sets(num_classes, k)) for _ in range(m)]
    return np.stack([s[0] for s in sets]), np.stack([s[1] for s in sets])


def run_bayes(labels, probs, K, *, prior_log=None, clamp=BIG_CLAMP):
    h = np.zeros((1, K), np.float32)
    for lab, p in zip(labels, probs, strict=True):
        h = fuse_bayes(h, lab[None], p[None], prior_log=prior_log, clamp=clamp)
    return h[0]


@settings(max_examples=150, deadline=None)
@given(st.integers(3, 40).flatmap(lambda K: st.tuples(st.just(K), measurement_sequences(K))), st.randoms())
def test_bayes_is_the_normalised_product_of_the_expanded_measurements_in_any_order(case, rnd):
    K, (labels, probs) = case
    h = run_bayes(labels, probs, K)
    expected = np.prod(expand_topk(labels, probs, K), axis=0)
    expected /= expected.sum()
    got = logodds_to_probs(h)
    assert got.sum() == pytest.approx(1.0) and h.max() == 0.0
    np.testing.assert_allclose(got, expected, rtol=2e-3, atol=1e-6)
    order = list(range(len(labels)))
    rnd.shuffle(order)
    np.testing.assert_allclose(logodds_to_probs(run_bayes(labels[order], probs[order], K)), got, rtol=2e-3,
                               atol=1e-6)


@settings(max_examples=100, deadline=None)
@given(st.integers(2, 8).flatmap(lambda K: st.tuples(st.just(K), st.lists(
    st.lists(st.floats(0.01, 1.0), min_size=K, max_size=K), min_size=1, max_size=5))))
def test_topk_with_k_equal_to_K_is_bayes(case):
    K, dists = case
    probs_full = np.array(dists, np.float64)
    probs_full /= probs_full.sum(1, keepdims=True)
    # each measurement as a full, sorted set of all K classes
    order = np.argsort(-probs_full, axis=1, kind="stable")
    labels = order.astype(np.uint16)
    probs = np.take_along_axis(probs_full, order, 1).astype(np.float32)
    tl = np.full((1, K), EMPTY, np.uint16)
    tp = np.zeros((1, K), np.float32)
    for lab, p in zip(labels, probs, strict=True):
        tl, tp = fuse_topk(tl, tp, lab[None], p[None], max_confidence=1.0)
    topk = np.zeros(K)
    used = tl[0] != EMPTY
    topk[tl[0][used]] = tp[0][used]
    bayes = logodds_to_probs(run_bayes(labels, probs, K))
    np.testing.assert_allclose(topk, bayes, rtol=2e-3, atol=2e-6)


@settings(max_examples=100, deadline=None)
@given(st.integers(3, 20).flatmap(lambda K: st.tuples(st.just(K), measurement_sequences(K), st.lists(
    st.floats(0.01, 1.0), min_size=K, max_size=K))))
def test_bayes_prior_divides_every_measurement_by_the_class_prior(case):
    K, (labels, probs), freq = case
    params = FusionParams(FusionRule.BAYES_PRIOR, prior=np.array(freq), prior_smoothing=0.0)
    h = run_bayes(labels, probs, K, prior_log=params.prior_logodds(K))
    prior = np.maximum(np.array(freq) / sum(freq), MIN_PROB)
    expected = np.prod(expand_topk(labels, probs, K) / prior, axis=0)
    np.testing.assert_allclose(logodds_to_probs(h), expected / expected.sum(), rtol=3e-3, atol=1e-6)
    uniform = FusionParams(FusionRule.BAYES_PRIOR, prior=np.array(freq), prior_smoothing=1.0).prior_logodds(K)
    np.testing.assert_allclose(logodds_to_probs(run_bayes(labels, probs, K, prior_log=uniform)),
                               logodds_to_probs(run_bayes(labels, probs, K)), rtol=1e-4, atol=1e-7)


@pytest.mark.slow
@settings(max_examples=100, deadline=None)
@given(st.integers(2, 12).flatmap(lambda K: st.tuples(st.just(K), measurement_sequences(K, max_len=10))),
       st.randoms())
def test_votes_count_argmax_labels_in_any_order(case, rnd):
    K, (labels, probs) = case
    counts = np.zeros((1, K), np.float32)
    for lab, p in zip(labels, probs, strict=True):
        counts = fuse_vote(counts, lab[None], p[None])
    assert counts[0].tolist() == np.bincount(labels[:, 0], minlength=K).tolist()
    order = list(range(len(labels)))
    rnd.shuffle(order)
    again = np.zeros((1, K), np.float32)
    for i in order:
        again = fuse_vote(again, labels[i][None], probs[i][None])
    assert np.array_equal(again, counts)


@settings(max_examples=150, deadline=None)
@given(st.integers(2, 12).flatmap(lambda K: measurement_sequences(K, max_len=8)), st.floats(0.97, 1.0))
def test_max_keeps_the_most_confident_measurement(seq, cap):
    labels, probs = seq
    lab, conf = np.array([EMPTY], np.uint16), np.zeros(1, np.float32)
    for z_l, z_p in zip(labels, probs, strict=True):
        lab, conf = fuse_max(lab, conf, z_l[None], z_p[None], max_confidence=cap)
        assert 0.0 < conf[0] <= cap
    best = int(np.argmax(probs[:, 0]))  # the first of equally confident measurements wins
    assert lab[0] == labels[best, 0] and conf[0] == pytest.approx(probs[best, 0])


def test_clamping_keeps_a_voxel_able_to_change_class():
    K, clamp = 10, 12.0
    a = (np.array([[3, EMPTY, EMPTY]], np.uint16), np.array([[0.8, 0, 0]], np.float32))
    b = (np.array([[7, EMPTY, EMPTY]], np.uint16), np.array([[0.8, 0, 0]], np.float32))
    h = np.zeros((1, K), np.float32)
    for _ in range(1000):
        h = fuse_bayes(h, *a, clamp=clamp)
    assert h.min() == -clamp and int(h.argmax()) == 3
    step = math.log(0.8 / (0.2 / 9))  # log-odds one measurement moves class 7 against class 3
    flips = next(n for n in range(1, 100) if int((h := fuse_bayes(h, *b, clamp=clamp)).argmax()) == 7)
    assert flips <= math.ceil(2 * clamp / step) + 1
    counts = np.zeros((1, K), np.float32)
    for _ in range(5000):
        counts = fuse_vote(counts, *a, cap=64)
    assert counts.max() <= 64
    votes = next(n for n in range(1, 200) if int((counts := fuse_vote(counts, *b, cap=64)).argmax()) == 7)
    assert votes <= 65
    lab, conf = fuse_max(np.array([3], np.uint16), np.array([0.99], np.float32),
                         np.array([[7, EMPTY]], np.uint16), np.array([[1.0, 0.0]], np.float32), max_confidence=0.99)
    assert lab[0] == 7 and conf[0] == pytest.approx(0.99)


def test_a_top_k_measurement_becomes_a_K_vector_with_others_spread_evenly():
    p = expand_topk(np.array([[2, 0, EMPTY]]), np.array([[0.6, 0.2, 0.0]]), 6)[0]
    assert p[2] == pytest.approx(0.6) and p[0] == pytest.approx(0.2)
    assert np.allclose(p[[1, 3, 4, 5]], 0.2 / 4) and p.sum() == pytest.approx(1.0)
    certain = expand_topk(np.array([[1]]), np.array([[1.0]]), 4)[0]
    assert certain[1] == 1.0 and np.all(certain[[0, 2, 3]] == MIN_PROB)


def test_rule_names_and_settings_are_validated():
    assert fusion_rule("bayes-prior") == FusionRule.BAYES_PRIOR and FusionParams(FusionRule.VOTE).entry.dense
    with pytest.raises(ConfigError, match="bayes"):
        fusion_rule("bayesian")
    with pytest.raises(ConfigError, match=r"1\.\.8"):
        FusionParams(FusionRule.TOPK, k=9)
    with pytest.raises(ConfigError, match="prior"):
        FusionParams(FusionRule.BAYES_PRIOR, prior=np.array([-1.0, 2.0]))
    mixed = FusionParams(FusionRule.BAYES_PRIOR, prior=np.array([0.0, 3.0]), prior_smoothing=0.5).prior_logodds(2)
    np.testing.assert_allclose(np.exp(mixed), [0.25, 0.75], rtol=1e-6)  # half uniform: an unseen class keeps 1/2K
    assert not FusionParams(FusionRule.BAYES, prior=np.array([1.0, 3.0])).prior_logodds(2).any()
    with pytest.raises(ConfigError, match="3 entries"):
        FusionParams(FusionRule.BAYES_PRIOR, prior=np.ones(3)).prior_logodds(5)
