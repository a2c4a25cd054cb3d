"""Issue 33, item 3: ``apply_temperature`` re-tempers a segmenter's probabilities as softmax(logits / T), on full
arrays and on top-k sets; ``--temperature`` (``semantics.temperature``) feeds fusion the tempered sets."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from semmap.config import SemanticsConfig
from semmap.errors import ConfigError
from semmap.perception.calibration import apply_temperature
from semmap.types import EMPTY_LABEL, TopKProbs


def _softmax(z: np.ndarray) -> np.ndarray:
    e = np.exp(z - z.max(-1, keepdims=True))
    return e / e.sum(-1, keepdims=True)


def _probs(seed: int = 0, shape=(50, 8), scale: float = 3.0) -> tuple[np.ndarray, np.ndarray]:
    z = np.random.default_rng(seed).normal(size=shape) * scale
    return z, _softmax(z)


def test_one_is_the_identity() -> None:
    _, p = _probs()
    assert np.array_equal(apply_temperature(p, 1.0), p)
    sets = TopKProbs.from_dense(p, 3)
    same = apply_temperature(sets, 1.0, num_classes=8)
    assert np.array_equal(same.probs, sets.probs) and np.array_equal(same.labels, sets.labels)


@pytest.mark.parametrize("t", [0.25, 0.5, 2.0, 10.0])
def test_full_arrays_equal_the_softmax_of_the_scaled_logits(t: float) -> None:
    z, p = _probs(1)
    np.testing.assert_allclose(apply_temperature(p, t), _softmax(z / t), atol=1e-12)
    assert apply_temperature(p.astype(np.float16), t).dtype == np.float16


def test_top_k_sets_with_every_class_kept_are_exact_and_partial_sets_keep_their_others() -> None:
    z, p = _probs(2, (40, 5))
    full = apply_temperature(TopKProbs.from_dense(p, 5), 3.0, num_classes=5)
    np.testing.assert_allclose(full.probs, TopKProbs.from_dense(_softmax(z / 3.0), 5).probs, atol=1e-6)
    top = TopKProbs.from_dense(p, 2)
    soft = apply_temperature(top, 3.0, num_classes=5)
    assert np.array_equal(soft.labels, top.labels)
    assert (soft.probs[:, 0] <= top.probs[:, 0] + 1e-7).all()  # the winner loses mass to the rest
    assert (soft.probs.sum(-1) <= 1 + 1e-6).all() and (soft.others >= 0).all()


def test_a_large_temperature_flattens_and_a_small_one_sharpens() -> None:
    _, p = _probs(3, (30, 6))
    flat = apply_temperature(p, 100.0)
    assert np.abs(flat - 1 / 6).max() < 0.02
    sharp = apply_temperature(p, 0.05)
    assert (sharp.max(-1) > 0.9).mean() > 0.9
    sets = apply_temperature(TopKProbs.from_dense(p, 3), 100.0, num_classes=6)
    assert np.abs(sets.probs - 1 / 6).max() < 0.02 and np.abs(sets.others - 0.5).max() < 0.03


def test_rows_without_classes_and_empty_slots_stay() -> None:
    labels = np.array([[2, EMPTY_LABEL, EMPTY_LABEL], [EMPTY_LABEL] * 3], np.uint16)
    probs = np.array([[0.9, 0, 0], [0, 0, 0]], np.float32)
    out = apply_temperature(TopKProbs(labels, probs), 4.0, num_classes=10)
    assert out.probs[1].sum() == 0 and (out.probs[0, 1:] == 0).all()
    assert 0.1 < out.probs[0, 0] < 0.9  # 0.9 against nine classes sharing 0.1, softened


@pytest.mark.parametrize("bad", [0.0, -1.0, float("nan"), float("inf"), 1e6, "x"])
def test_a_bad_temperature_is_refused_in_one_line(bad) -> None:
    with pytest.raises(ConfigError, match="temperature"):
        apply_temperature(np.array([0.5, 0.5]), bad)
    with pytest.raises(ConfigError, match="temperature"):
        SemanticsConfig(temperature=bad)


@settings(max_examples=60, deadline=None)
@given(logits=arrays(np.float64, st.tuples(st.integers(1, 6), st.integers(2, 7)),
                     elements=st.floats(-20, 20, allow_nan=False)),
       t=st.floats(0.05, 50.0), k=st.integers(1, 7))
def test_property_order_kept_sums_kept_and_matches_the_scaled_softmax(logits, t, k) -> None:
    p = _softmax(logits)
    q = apply_temperature(p, t)
    np.testing.assert_allclose(q.sum(-1), 1.0, atol=1e-9)
    np.testing.assert_allclose(q, _softmax(logits / t), atol=1e-9)
    # the order of the classes never changes (ties may only stay ties)
    i, j = np.triu_indices(p.shape[-1], 1)
    assert ((p[:, i] > p[:, j] + 1e-12) <= (q[:, i] >= q[:, j])).all()
    sets = TopKProbs.from_dense(p, min(k, p.shape[-1]))
    out = apply_temperature(sets, t, num_classes=p.shape[-1])
    assert np.array_equal(out.labels, sets.labels)
    assert (np.diff(out.probs, axis=-1) <= 1e-6).all()  # still sorted by decreasing probability
    assert (out.probs.sum(-1) <= 1 + 1e-5).all()


def test_a_run_fuses_the_tempered_sets(tmp_path) -> None:
    """``semantics.temperature`` reaches fusion: label images softened at T = 4 leave the map less sure of the
    same classes than at T = 1."""
    from helpers import make_room_frames, room_label_set
    from semmap.config import InputConfig, MappingConfig, OutputConfig, RunConfig
    from semmap.io.tum_writer import write_tum_sequence
    from semmap.pipeline import Pipeline

    write_tum_sequence(tmp_path / "seq", make_room_frames(3), label_set=room_label_set())
    clouds = {}
    for t in (1.0, 4.0):
        config = RunConfig(input=InputConfig(dataset=tmp_path / "seq"), mapping=MappingConfig(resolution=0.1),
                           semantics=SemanticsConfig(source="labels", temperature=t),
                           output=OutputConfig(out=tmp_path / f"out{t:g}", plots=False, preview=False, cloud=False))
        result = Pipeline(config).run()
        clouds[t] = result.maps[0].cloud()
        assert ("temperature" in result.report["ms_per_frame"]) == (t != 1.0)
    assert (clouds[1.0].labels == clouds[4.0].labels).mean() > 0.9  # (the top-k rule may flip a boundary voxel)
    assert clouds[4.0].confidence.mean() < clouds[1.0].confidence.mean() - 0.05
