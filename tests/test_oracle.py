"""Oracle segmenter: presets, accuracy control, structured errors, determinism, speed-independent checks."""

from __future__ import annotations

import numpy as np
import pytest

from semmap.errors import ConfigError, DatasetError
from semmap.labels import INDOOR_LABELS
from semmap.perception.base import Segmenter
from semmap.perception.oracle import CONFUSIONS, OracleSegmenter, measured_accuracy
from semmap.sim.export import simulate_frames
from semmap.sim.scene import generate_scene
from semmap.sim.trajectory import make_trajectory
from semmap.types import EMPTY_LABEL


@pytest.fixture(scope="module")
def frames():
    """Rendered frames (full resolution, with labels and instances) from two scenes and trajectories."""
    out = []
    for seed, kind, traj in ((0, "office", "loop"), (1, "living_room", "orbit")):
        scene = generate_scene(seed, kind, "small")
        poses = make_trajectory(scene, traj, 60, seed=seed)[::10]
        out += list(simulate_frames(scene, poses, noise=False))
    return [f.with_(index=i) for i, f in enumerate(out)]


def test_is_a_segmenter_with_the_label_set():
    seg = OracleSegmenter(INDOOR_LABELS)
    assert isinstance(seg, Segmenter)
    assert seg.label_set is INDOOR_LABELS


@pytest.mark.slow
def test_bad_arguments_raise(frames):
    with pytest.raises(ConfigError):
        OracleSegmenter(INDOOR_LABELS, preset="perfect")
    with pytest.raises(ConfigError):
        OracleSegmenter(INDOOR_LABELS, pixel_acuracy=0.8)
    with pytest.raises(ConfigError):
        OracleSegmenter(INDOOR_LABELS, pixel_accuracy=1.5)
    with pytest.raises(DatasetError):
        OracleSegmenter(INDOOR_LABELS).segment(frames[0].with_(labels=None))


def test_paper_preset_puts_0_9_on_the_true_class_and_spreads_the_rest(frames):
    seg = OracleSegmenter(INDOOR_LABELS, preset="voxel-grid-paper")
    f = frames[0]
    out = seg.segment(f)
    K = len(INDOOR_LABELS)
    assert out.labels.shape == (*f.labels.shape, 3) and out.labels.dtype == np.uint16
    assert np.array_equal(out.argmax(), f.labels)
    assert np.allclose(out.probs[..., 0], 0.9)
    assert np.allclose(out.probs[..., 1:], 0.1 / (K - 2))
    assert np.allclose(out.others, 0.1 - 2 * 0.1 / (K - 2), atol=1e-6)
    wall = f.labels == INDOOR_LABELS.id_of("wall")
    assert (out.labels[wall][:, 1:] == [2, 3]).all()  # the two lowest other real classes
    assert measured_accuracy(seg, frames) == 1.0


@pytest.mark.parametrize("preset,overrides,target", [
    ("cnn-like", {}, 0.75),
    ("cnn-like", {"pixel_accuracy": 0.9}, 0.9),
    ("voxel-grid-paper", {"pixel_accuracy": 0.85}, 0.85),
])
def test_measured_accuracy_matches_the_setting(frames, preset, overrides, target):
    seg = OracleSegmenter(INDOOR_LABELS, preset=preset, seed=3, **overrides)
    assert abs(measured_accuracy(seg, frames) - target) <= 0.02


def test_cnn_like_probabilities_are_soft_sorted_and_second_is_often_true(frames):
    seg = OracleSegmenter(INDOOR_LABELS, seed=1)
    wrong_total = second_true = 0
    for f in frames:
        out = seg.segment(f)
        p = out.probs
        valid = f.labels > 0
        assert (p[..., 0][valid] >= 0.5 - 1e-6).all() and (p[..., 0][valid] <= 0.9 + 1e-6).all()
        assert (np.diff(p, axis=-1) <= 1e-7).all()
        assert (p.sum(-1) <= 1 + 1e-5).all()
        labels = out.labels
        used = labels != EMPTY_LABEL
        assert (labels[..., 0] != labels[..., 1])[used[..., 1]].all()
        assert (labels[..., 1] != labels[..., 2])[used[..., 2]].all()
        wrong = valid & (out.argmax() != f.labels)
        wrong_total += int(wrong.sum())
        second_true += int((labels[..., 1][wrong] == f.labels[wrong]).sum())
    assert second_true / wrong_total > 0.6


def test_cnn_like_errors_are_structured_not_salt_and_pepper(frames):
    seg = OracleSegmenter(INDOOR_LABELS, seed=2)
    names = INDOOR_LABELS.names
    confusable = partner_hits = 0
    boundary_err = interior_err = boundary_n = interior_n = 0
    for f in frames:
        pred = seg.segment(f).argmax()
        gt = f.labels
        wrong = (pred != gt) & (gt > 0)
        # errors cluster in patches: most wrong pixels have wrong 4-neighbours too
        neighbours = wrong[1:-1, :-2] & wrong[1:-1, 2:] & wrong[:-2, 1:-1] & wrong[2:, 1:-1]
        assert neighbours.sum() > 0.6 * wrong[1:-1, 1:-1].sum()
        # errors are denser next to class boundaries than inside regions
        edge = np.zeros(gt.shape, bool)
        edge[:, 1:] |= gt[:, 1:] != gt[:, :-1]
        edge[1:, :] |= gt[1:, :] != gt[:-1, :]
        near = np.zeros_like(edge)
        for dy in range(-3, 4):
            near |= np.roll(edge, dy, axis=0)
        near2 = near.copy()
        for dx in range(-3, 4):
            near2 |= np.roll(near, dx, axis=1)
        boundary_err += int(wrong[near2].sum())
        boundary_n += int((near2 & (gt > 0)).sum())
        interior_err += int(wrong[~near2].sum())
        interior_n += int((~near2 & (gt > 0)).sum())
        # wrong object pixels are often predicted as the typical confusion partner
        for c in np.unique(gt[wrong]):
            partners = {INDOOR_LABELS.id_of(p) for p in CONFUSIONS.get(names[c], ()) if p in names}
            sel = wrong & (gt == c)
            if partners and names[c] not in ("wall", "floor", "ceiling"):
                confusable += int(sel.sum())
                partner_hits += int(np.isin(pred[sel], list(partners)).sum())
    assert boundary_err / boundary_n > 1.5 * interior_err / interior_n
    assert partner_hits / confusable > 0.3


def test_deterministic_per_frame_and_flickers_between_frames(frames):
    a = OracleSegmenter(INDOOR_LABELS, seed=7)
    b = OracleSegmenter(INDOOR_LABELS, seed=7)
    out_a = a.segment(frames[2])
    b.segment(frames[0])  # call order must not matter
    out_b = b.segment(frames[2])
    assert np.array_equal(out_a.labels, out_b.labels) and np.array_equal(out_a.probs, out_b.probs)
    moved = a.segment(frames[2].with_(index=99))
    assert not np.array_equal(out_a.labels, moved.labels)
    other_seed = OracleSegmenter(INDOOR_LABELS, seed=8).segment(frames[2])
    assert not np.array_equal(out_a.labels, other_seed.labels)


def test_void_pixels_stay_unknown_and_k_is_respected(frames):
    f = frames[1]
    labels = f.labels.copy()
    labels[:10] = 0
    out = OracleSegmenter(INDOOR_LABELS, k=2).segment(f.with_(labels=labels))
    assert out.k == 2
    assert (out.labels[:10, :, 0] == 0).all() and np.allclose(out.probs[:10, :, 0], 1.0)
    assert (out.labels[:10, :, 1] == EMPTY_LABEL).all()
    wide = OracleSegmenter(INDOOR_LABELS, k=5).segment(f)
    assert wide.k == 5 and (wide.labels[..., 3:] == EMPTY_LABEL).all()
