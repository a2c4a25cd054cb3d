"""Map-at-pixel evaluation (eval.pixels, semmap eval-map) and the OctoMap's mean cell evidence (issue 33)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from helpers import make_room_frames, room_label_set, write_png
from semmap.errors import ConfigError
from semmap.eval.pixels import PixelRecord, PixelScores, frame_sample, fusion_ceiling, map_labels_at
from semmap.eval.semantic import confusion, scores
from semmap.maps.semantic_octomap import CellEvidence, SemanticOctoMap
from semmap.maps.voxel_grid import SemanticVoxelGrid
from semmap.pipeline import Mapper
from semmap.types import EMPTY_LABEL, CameraIntrinsics, Frame, TopKProbs

E = int(EMPTY_LABEL)
WALL_CAMERA = CameraIntrinsics(32, 24, 30.0, 30.0, 15.5, 11.5)


def wall_frame(index: int = 0) -> Frame:
    """A camera at the origin looking along +z at a wall 2 m away: class 1 left of x = 0, class 2 right of it."""
    h, w = WALL_CAMERA.height, WALL_CAMERA.width
    labels = np.where(np.arange(w)[None, :] < 16, 1, 2).repeat(h, 0).astype(np.uint16)
    return Frame(index=index, timestamp=float(index), rgb=np.zeros((h, w, 3), np.uint8),
                 depth=np.full((h, w), 2.0, np.float32), intrinsics=WALL_CAMERA, T_world_cam=np.eye(4),
                 labels=labels, name=str(index))


def noisy(frame: Frame, rate: float, rng: np.random.Generator, classes: int) -> TopKProbs:
    """A network that is right except at a random ``rate`` of the pixels (independent per frame), where it says
    another class with the same confidence."""
    wrong = rng.random(frame.labels.shape) < rate
    shift = rng.integers(1, classes - 1, frame.labels.shape)
    labels = np.where(wrong, (frame.labels - 1 + shift) % (classes - 1) + 1, frame.labels).astype(np.uint16)
    return TopKProbs.from_hard_labels(labels, 0.8, classes, 3)


def test_scores_count_only_pixels_where_both_give_a_label():
    acc = PixelScores(3)
    gt = np.array([1, 1, 2, 2, 2])
    net = np.array([1, 2, 2, E, 2])
    mapped = np.array([1, 1, E, 2, 2])
    acc.add(gt, net, mapped)  # pixel 2: no map label; pixel 3: no network label -> both left out
    assert acc.eligible == 4 and acc.scored == 3
    assert acc.conf_map.sum() == acc.conf_net.sum() == 3
    s = acc.summary()
    assert s["pixel_coverage"] == 0.75
    assert s["pixel_accuracy_map"] == 1.0 and s["pixel_accuracy_network"] == round(2 / 3, 4)
    expected_net = scores(confusion(np.array([1, 2, 2]), np.array([1, 1, 2]), 3)).miou
    assert s["pixel_miou_network"] == round(expected_net, 4)
    assert s["pixel_gain"] == round(1.0 - expected_net, 4)
    acc_map_only = PixelScores(3)
    acc_map_only.add(gt, None, mapped)
    assert "pixel_miou_network" not in acc_map_only.summary() and acc_map_only.eligible == 5


def test_the_maps_label_at_a_known_pixel_is_the_voxel_it_falls_into():
    frame = wall_frame()
    m = SemanticOctoMap(0.1, label_set=room_label_set())
    Mapper([m], min_depth=0.1, max_depth=5.0).integrate(frame, frame.T_world_cam,
                                                        TopKProbs.from_hard_labels(frame.labels, 0.9, 7, 3))
    s = frame_sample(frame, frame.T_world_cam, None)
    labels = map_labels_at(m, s.points)
    assert len(s.gt) == 32 * 24 and (s.net == E).all()
    left = s.points[:, 0] < -0.05  # pixels clear of the voxel column at x = 0
    assert (labels[left] == 1).all() and (labels[s.points[:, 0] > 0.05] == 2).all()
    row, col = 12, 3  # a known pixel: row-major index among the sampled pixels
    assert labels[row * 32 + col] == 1 and s.gt[row * 32 + col] == 1
    assert (map_labels_at(m, np.array([[0.0, 0.0, 4.0]])) == E).all()  # behind the wall: nothing


@pytest.mark.parametrize("make_map", [
    lambda ls: SemanticOctoMap(0.1, label_set=ls, cell_evidence=CellEvidence.MEAN),
    lambda ls: SemanticVoxelGrid(0.1, label_set=ls)], ids=["octomap-mean", "voxelgrid"])
def test_independent_network_errors_fuse_into_a_better_map_and_the_causal_map_lags(make_map):
    ls = room_label_set()
    frames = make_room_frames(8)
    rng = np.random.default_rng(0)
    m = make_map(ls)
    mapper = Mapper([m], min_depth=0.1, max_depth=6.0)
    record = PixelRecord(every=1, stride=1)
    for f in frames:
        sem = noisy(f, 0.3, rng, len(ls))
        record.add(f, f.T_world_cam, sem, [m], min_depth=0.1, max_depth=6.0)
        s = record.samples[-1]
        assert (s.net[s.gt == s.net].size / s.gt.size) == pytest.approx(0.7, abs=0.05)
        mapper.integrate(f, f.T_world_cam, sem)
    r = record.report(m)
    assert r["pixel_frames"] == 8 and r["pixel_coverage"] > 0.9
    assert r["pixel_miou_network"] < 0.75
    assert r["pixel_miou_map"] > r["pixel_miou_network"] + 0.15, r
    assert r["pixel_gain"] == pytest.approx(r["pixel_miou_map"] - r["pixel_miou_network"], abs=2e-4)
    # causal: the first frame met an empty map, later ones a map of fewer views than the final one
    assert (record.samples[0].causal[m.kind.value] == E).all()
    assert r["pixel_coverage_causal"] < r["pixel_coverage"]
    assert r["pixel_miou_map_causal"] < r["pixel_miou_map"]
    # the ceiling: independent errors leave the plurality right almost everywhere
    assert r["ceiling_voxel_accuracy"] > 0.9 and r["unreachable_share"] < 0.05
    state = record.state()
    again = PixelRecord(every=1, stride=1)
    again.restore(state)
    assert again.report(m) == r  # a checkpoint keeps the samples exactly


def test_mean_evidence_sees_every_point_of_a_voxel_first_only_the_first():
    ls = room_label_set()
    pts = np.array([[0.01, 0.01, 1.01], [0.02, 0.02, 1.02], [0.03, 0.03, 1.03]])  # one 10 cm voxel
    labels = np.array([[3, E, E], [4, E, E], [4, E, E]], np.uint16)
    probs = np.array([[0.9, 0, 0], [0.6, 0, 0], [0.6, 0, 0]], np.float32)
    out = {}
    for ev in CellEvidence:
        m = SemanticOctoMap(0.1, label_set=ls, cell_evidence=ev)
        m.insert_points(pts, np.zeros(3), semantics=TopKProbs(labels, probs))
        out[ev] = m
    first, mean = out[CellEvidence.FIRST].voxels(), out[CellEvidence.MEAN].voxels()
    assert first.labels[0, 0] == 3 and first.probs[0, 0] == pytest.approx(0.9)
    assert list(mean.labels[0, :2]) == [4, 3] and mean.probs[0, :2] == pytest.approx([0.4, 0.3])
    np.testing.assert_array_equal(first.logodds, mean.logodds)  # occupancy is OctoMap's either way
    with pytest.raises(ConfigError, match="cell evidence"):
        SemanticOctoMap(0.1, cell_evidence="median")


def test_ceiling_counts_voxels_whose_views_mostly_err():
    pts = np.array([[0.01, 0, 0]] * 3 + [[0.31, 0, 0]] * 3)
    gt = np.array([1, 1, 1, 2, 2, 2])
    net = np.array([1, 1, 2, 3, 3, 3])  # voxel 1: plurality right; voxel 2: the true class never seen
    c = fusion_ceiling(pts, gt, net, 0.1)
    assert c == {"ceiling_voxels": 2, "ceiling_voxel_accuracy": 0.5, "unreachable_share": 0.5,
                 "plurality_wrong_share": 0.5}


def test_eval_map_scores_a_saved_map_against_stored_predictions(tmp_path):
    from typer.testing import CliRunner

    from semmap.cli import app
    from semmap.datasets import open_dataset
    from semmap.io.map_files import save_map
    from semmap.io.tum_writer import write_tum_sequence

    ls = room_label_set()
    write_tum_sequence(tmp_path / "seq", make_room_frames(6), label_set=ls)
    frames = list(open_dataset(tmp_path / "seq"))  # as eval-map reads them (the room's walls lie on voxel faces)
    rng = np.random.default_rng(1)
    m = SemanticOctoMap(0.1, label_set=ls, cell_evidence=CellEvidence.MEAN)
    mapper = Mapper([m], min_depth=0.1, max_depth=6.0)
    expected = PixelScores(len(ls))
    samples = []
    for f in frames:
        sem = noisy(f, 0.3, rng, len(ls))
        write_png(tmp_path / "preds" / f"{f.name}.png", sem.labels[..., 0])
        mapper.integrate(f, f.T_world_cam, sem)
        samples.append(frame_sample(f, f.T_world_cam, sem, min_depth=0.3, max_depth=6.0))
    for s in samples[::2]:
        expected.add(s.gt, s.net, map_labels_at(m, s.points))
    save_map(tmp_path / "map.semmap", m)
    r = CliRunner().invoke(app, ["eval-map", str(tmp_path / "map.semmap"), str(tmp_path / "seq"), "--segmenter",
                                 "precomputed", "--weights", str(tmp_path / "preds"), "--every", "2", "--out",
                                 str(tmp_path / "s.json")])
    assert r.exit_code == 0, r.output
    got = json.loads((tmp_path / "s.json").read_text())
    assert got["pixel_frames"] == 3 and got["kind"] == "octomap"
    want = expected.summary()
    for key in ("pixel_miou_map", "pixel_miou_network", "pixel_coverage", "pixels_scored"):
        assert got[key] == want[key], key
    assert got["pixel_miou_map"] > got["pixel_miou_network"]
    r = CliRunner().invoke(app, ["eval-map", str(tmp_path / "map.semmap"), str(tmp_path / "seq")])
    assert r.exit_code == 0 and "pixel_miou_network" not in json.loads(r.output)  # map-only scores
