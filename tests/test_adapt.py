"""semmap adapt: pseudo-labels rendered from a hand-built map, the masks of unsure pixels, a short adaptation that
lowers the loss on its pseudo-labels, resuming after a kill, and the refusal of segmenters it cannot train."""

from __future__ import annotations

import copy
import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from helpers import make_room_frames, room_label_set, write_png
from semmap.errors import ConfigError, DatasetError
from semmap.labels import INDOOR_LABELS
from semmap.maps.semantic_octomap import SemanticOctoMap
from semmap.perception.networks.registry import load_weights
from semmap.perception.voc import PASCAL_VOC
from semmap.pipeline import Mapper
from semmap.train.adapt import Adapter, AdaptSettings, AdaptSource, adapt
from semmap.train.class_weights import IGNORE
from semmap.train.pseudo_labels import MaskSettings, ViewCounter, confident_network, depth_edges, pseudo_labels
from semmap.train.trainable import _voc_classes, by_name, load_trainable
from semmap.train.trainer import TrainSettings, batch_tensors, normalise, train
from semmap.types import CameraIntrinsics, Frame, LabelSet, TopKProbs, Trajectory, make_pose

RES = 0.1
NO_MASKS = MaskSettings(min_confidence=0.0, min_views=0, edge_px=0, edge_jump_m=100.0, edge_jump_share=100.0)


@pytest.fixture(scope="module")
def room():
    """Frames of the analytic box room and an OctoMap fused from their true labels (confidence 0.9)."""
    frames = make_room_frames(12)
    labels = room_label_set()
    m = SemanticOctoMap(RES, label_set=labels)
    mapper = Mapper([m], min_depth=0.1, max_depth=10.0)
    for f in frames:
        mapper.integrate(f, f.T_world_cam, TopKProbs.from_hard_labels(f.labels, 0.9, len(labels)))
    return frames, m


def test_pseudo_labels_render_the_maps_class_at_each_pixels_point(room):
    frames, m = room
    agree, total = 0, 0
    for f in frames[::3]:
        p = pseudo_labels(m, f, f.T_world_cam, None, NO_MASKS)
        assert p.labels.shape == f.depth.shape
        has = p.map_labels != IGNORE
        assert has.mean() > 0.9  # the map covers what its frames saw
        agree += int((p.map_labels[has] == f.labels[has]).sum())
        total += int(has.sum())
        np.testing.assert_array_equal(p.labels, p.map_labels)  # no mask: every labelled pixel teaches
        assert np.median(p.confidence[has]) > 0.8 and not p.confidence[~has].any()
    assert agree / total > 0.9  # the walls' labels come back, but for voxels straddling two walls


def test_pseudo_labels_on_a_coarser_grid_are_every_strideth_pixel(room):
    frames, m = room
    f = frames[4]
    full = pseudo_labels(m, f, f.T_world_cam, None, NO_MASKS)
    half = pseudo_labels(m, f, f.T_world_cam, None, NO_MASKS, stride=2)
    assert half.labels.shape == (30, 40)
    np.testing.assert_array_equal(half.map_labels, full.map_labels[::2, ::2])


class _HandBuiltMap:
    """A map whose class depends on the world x of the point: x < 0 class 1 (sure), x >= 0 class 2 (unsure)."""

    resolution = RES
    label_set = LabelSet.generic(3)

    def class_at(self, points):
        x = np.asarray(points)[:, 0]
        return (np.where(x < 0, 1, 2).astype(np.uint16),
                np.where(x < 0, 0.9, 0.3).astype(np.float32))


def _wall_frame(box: bool = True) -> Frame:
    """A wall 2 m ahead of a camera at the origin looking along +z, with a box 1 m ahead in the upper left."""
    cam = CameraIntrinsics(40, 30, 30.0, 30.0, 19.5, 14.5)
    depth = np.full((30, 40), 2.0, np.float32)
    if box:
        depth[:8, :8] = 1.0
    return Frame(index=0, timestamp=0.0, rgb=np.zeros((30, 40, 3), np.uint8), depth=depth, intrinsics=cam,
                 T_world_cam=make_pose(np.eye(3), [0.0, 0.0, 0.0]))


def test_masks_drop_low_confidence_few_views_and_depth_edges():
    f = _wall_frame()
    m = _HandBuiltMap()
    views = ViewCounter(RES)
    views.add(f, f.T_world_cam)
    settings = MaskSettings(min_confidence=0.5, min_views=1, edge_px=1)
    p = pseudo_labels(m, f, f.T_world_cam, views, settings)
    left = np.zeros((30, 40), bool)
    left[:, :20] = True  # x < 0 at the wall (u < cx = 19.5)
    edge = depth_edges(f.depth, radius=1, jump_m=0.1, jump_share=0.05)
    assert edge[7, 3] and edge[8, 3] and edge[3, 8] and not edge[20, 3]  # both sides of the box's outline
    np.testing.assert_array_equal(p.labels != IGNORE, left & ~edge)
    assert (p.labels[left & ~edge] == 1).all()
    assert p.removed["low_confidence"] > 0 and p.removed["depth_edge"] > 0 and p.removed["few_views"] == 0
    assert p.kept + sum(p.removed.values()) == p.with_depth == 30 * 40
    strict = pseudo_labels(m, f, f.T_world_cam, views, MaskSettings(min_confidence=0.5, min_views=2, edge_px=1))
    assert strict.kept == 0 and strict.removed["few_views"] > 0  # one frame saw each voxel: the network's own guess
    views.add(f, f.T_world_cam)  # a second view of the same voxels
    again = pseudo_labels(m, f, f.T_world_cam, views, MaskSettings(min_confidence=0.5, min_views=2, edge_px=1))
    np.testing.assert_array_equal(again.labels, p.labels)


def test_a_network_sure_of_another_class_vetoes_the_maps_label():
    p = pseudo_labels(_HandBuiltMap(), _wall_frame(box=False), np.eye(4), None, NO_MASKS)
    network = np.where(np.arange(40) < 10, 2, 1).astype(np.uint16)[None].repeat(30, 0)  # class 2 at u < 10
    confidence = np.full((30, 40), 0.9, np.float32)
    confidence[:15] = 0.6  # unsure in the upper half
    before = p.labels.copy()
    confident_network(p, network, confidence, 0.7)
    vetoed = (before != p.labels)
    disagree = np.zeros((30, 40), bool)
    disagree[:, :10] = disagree[:, 20:] = True  # the map says 1 left of u = 20, 2 right of it
    np.testing.assert_array_equal(vetoed, disagree & (confidence >= 0.7))
    assert (p.labels[vetoed] == IGNORE).all() and p.removed["confident_network"] == 15 * 30


def test_depth_edges_mark_holes_and_jumps_relative_to_depth():
    d = np.full((10, 10), 4.0, np.float32)
    d[:, 5:] = 4.15  # 15 cm at 4 m: under 5 %, no edge
    assert not depth_edges(d, radius=0, jump_m=0.1, jump_share=0.05).any()
    d[:, 5:] = 4.5
    e = depth_edges(d, radius=0, jump_m=0.1, jump_share=0.05)
    assert e[:, 4:6].all() and not e[:, :4].any() and not e[:, 6:].any()
    d[:] = 4.0
    d[2, 2] = 0.0  # a hole
    e = depth_edges(d, radius=1, jump_m=0.1, jump_share=0.05)
    assert depth_edges(d, radius=0, jump_m=0.1, jump_share=0.05).sum() == 5  # the hole and its 4 neighbours
    assert e[0:5, 0:5].sum() == e.sum() == 25 - 4  # that cross grown by one pixel: 5x5 less its corners


def test_map_classes_reach_the_network_by_name_and_espnetv2_through_the_voc_fold(trained):
    net = LabelSet(("unknown", "wall", "floor"), np.zeros((3, 3), np.uint8))
    mapped = LabelSet(("unknown", "floor", "chair", "wall"), np.zeros((4, 3), np.uint8))
    np.testing.assert_array_equal(by_name(mapped, net), [0, 2, 0, 1])
    voc = {name: i for i, name in enumerate(("unknown", *PASCAL_VOC.names))}  # VOC's classes moved up one
    lut = _voc_classes(INDOOR_LABELS, None)
    assert lut[INDOOR_LABELS.id_of("table")] == voc["diningtable"] and lut[INDOOR_LABELS.id_of("chair")] == voc["chair"]
    assert lut[INDOOR_LABELS.id_of("wall")] == lut[INDOOR_LABELS.id_of("cabinet")] == voc["background"]
    network = load_trainable("fcn", trained)
    assert network.lut(room_label_set())[0] == IGNORE  # the map's own "unknown" teaches nothing
    with pytest.raises(ConfigError, match="share none"):
        network.lut(LabelSet(("unknown", "sofa"), np.zeros((2, 3), np.uint8)))


# ------------------------------------------------------------------ adaptation
@pytest.fixture(scope="module")
def trained(tmp_path_factory) -> Path:
    """A small FCN trained a little on other views of the room (as a network is before it meets a new scene)."""
    root = tmp_path_factory.mktemp("trained")
    for f in make_room_frames(8, start=2.0):
        write_png(root / "data" / "images" / f"{f.name}.png", f.rgb[..., ::-1])
        write_png(root / "data" / "labels" / f"{f.name}.png", f.labels)
    room_label_set().save(root / "data" / "labelset.json")
    result = train(TrainSettings(model="fcn", data=(root / "data",), out=root / "run", iterations=30, batch=4,
                                 lr=0.02, input_size=(40, 30), width=0.125, eval_every=30, threads=1,
                                 val_fraction=0.25))
    return result.final


def _weights(tmp_path: Path, trained: Path) -> Path:
    """A copy of the trained network's weight file (adaptation records the file it started from)."""
    return Path(shutil.copy(trained, tmp_path / "start.pt"))


def _source(room, weights: Path, run_dir: Path) -> AdaptSource:
    frames, m = room
    run_dir.mkdir(exist_ok=True)
    trajectory = Trajectory(np.array([f.timestamp for f in frames]), np.stack([f.T_world_cam for f in frames]))
    return AdaptSource(run_dir=run_dir, frames=lambda: iter(frames), length=len(frames), trajectory=trajectory,
                       map=m, weights=weights, segmenter="fcn", min_depth=0.1, max_depth=10.0)


def _settings(out: Path, **kw) -> AdaptSettings:
    base = dict(out=out, steps=2, batch=2, replay_share=0.0, lr=0.01, eval_every=1, threads=1, augment=False,
                holdout_every=4, anchor=0.0, masks=MaskSettings(min_views=2, network_confidence=None))
    return AdaptSettings(**(base | kw))


def _pseudo_loss(adapter: Adapter, state: dict) -> float:
    """Cross entropy of the pseudo-labelled training frames under the network weights ``state``."""
    model = copy.deepcopy(adapter.model)
    model.load_state_dict(state)
    model.eval()
    ds = adapter.data.train
    rgb, labels, _ = batch_tensors(ds, np.arange(len(ds)), False)
    with torch.no_grad():
        logits, _ = model.forward_train(normalise(rgb))
    return float(torch.nn.functional.cross_entropy(logits, labels, ignore_index=IGNORE))


def test_two_steps_lower_the_loss_on_the_pseudo_labels_and_write_the_outputs(room, trained, tmp_path):
    weights = _weights(tmp_path, trained)
    out = tmp_path / "adapted"
    adapter = Adapter(_source(room, weights, tmp_path / "run"), _settings(out))
    assert len(adapter.data.train) == 9 and len(adapter.data.holdout) == 3  # every 4th frame held out
    assert adapter.data.train.labels.shape[1:] == (30, 40)  # the network's input size
    assert adapter.data.stats["coverage"] > 0.5 and adapter.data.stats["accuracy"] > 0.9
    start = load_weights(weights).model.state_dict()
    before = _pseudo_loss(adapter, start)
    result = adapter.run()
    after = _pseudo_loss(adapter, _last_state(out))  # the network after its last step
    assert after < before
    for name in ("best.pt", "manifest.json", "report.json", "report.md", "curve.png", "log.csv", "pseudo_labels.npz",
                 "pseudo_labels.png", "last.pt"):
        assert (out / name).is_file(), name
    report = json.loads((out / "report.json").read_text())
    assert [r["step"] for r in report["rows"]] == [0, 1, 2]
    assert report["pseudo_labels"]["accuracy"] > 0.9 and report["cpu_minutes"] > 0
    manifest = json.loads((out / "manifest.json").read_text())["networks"]["fcn"]
    assert manifest["file"] == "best.pt" and manifest["adapted_from"]["file"] == str(weights)
    adapted = load_weights(result.weights)
    assert adapted.meta["adapt"]["best_step"] == report["best"]["step"]
    assert adapted.meta["temperature"] == report["calibration"]["temperature"] > 0


def _last_state(out: Path) -> dict:
    return torch.load(out / "last.pt", weights_only=True)["model"]


@pytest.mark.slow
def test_an_adaptation_killed_after_a_checkpoint_resumes_to_the_same_weights(room, trained, tmp_path):
    weights = _weights(tmp_path, trained)
    source = _source(room, weights, tmp_path / "run")
    whole = adapt(source, _settings(tmp_path / "whole", steps=3))
    assert adapt(source, _settings(tmp_path / "cut", steps=3), stop_after=1) is None  # killed after step 1
    with pytest.raises(ConfigError, match="--resume"):
        adapt(source, _settings(tmp_path / "cut", steps=3))
    with pytest.raises(ConfigError, match="different settings"):
        adapt(source, _settings(tmp_path / "cut", steps=3, lr=0.02), resume=True)
    resumed = adapt(source, _settings(tmp_path / "cut", steps=3), resume=True)
    a, b = load_weights(whole.weights).model.state_dict(), load_weights(resumed.weights).model.state_dict()
    assert all(torch.equal(a[k], b[k]) for k in a)
    rows = [json.loads((p / "report.json").read_text())["rows"] for p in (tmp_path / "whole", tmp_path / "cut")]
    strip = [[{k: v for k, v in r.items() if k != "cpu_s"} for r in rr] for rr in rows]
    assert strip[0] == strip[1]


def test_a_map_without_a_class_at_any_pixel_teaches_nothing_and_says_so(room, trained, tmp_path):
    frames, _ = room
    empty = SemanticOctoMap(RES, label_set=room_label_set())
    source = _source((frames, empty), _weights(tmp_path, trained), tmp_path / "run")
    with pytest.raises(DatasetError, match="no pseudo-label survived"):
        Adapter(source, _settings(tmp_path / "out"))


@pytest.mark.slow  # (ESPNetv2 at 432x320: over 5 s)
def test_espnetv2_adapts_with_voc_background_as_a_class_and_its_file_reads_back(room, tmp_path):
    """ESPNetv2 (PASCAL VOC) learns from a map in semmap's classes: wall and floor are VOC's background; the adapted
    file is an ESPNetv2 weights file that --segmenter espnetv2 --weights reads, with its temperature."""
    from semmap.perception.registry import make_segmenter, shipped_espnetv2

    frames = room[0][:6]
    faces = np.array([0, 1, 1, 1, 1, 2, 3])  # room face -> wall, wall, wall, wall, floor, ceiling (indoor ids)
    indoor = SemanticOctoMap(RES, label_set=INDOOR_LABELS)
    mapper = Mapper([indoor], min_depth=0.1, max_depth=10.0)
    for f in frames:
        mapper.integrate(f, f.T_world_cam, TopKProbs.from_hard_labels(faces[f.labels], 0.9, len(INDOOR_LABELS)))
    weights = Path(shutil.copy(shipped_espnetv2("s1"), tmp_path / "espnetv2.pth"))
    source = _source((frames, indoor), weights, tmp_path / "run")
    source.segmenter = "espnetv2"
    settings = _settings(tmp_path / "adapted", lr=0.001, freeze_norm=True, eval_every=2, holdout_every=3)
    adapter = Adapter(source, settings)
    assert adapter.data.train.rgb.shape[1:3] == (320, 432)  # ESPNetv2's input: short side 320
    taught = np.unique(adapter.data.train.labels)
    assert set(taught) <= {IGNORE, 1} and 1 in taught  # everything the map names is VOC's background (id 0 + 1)
    before = _pseudo_loss(adapter, load_trainable("espnetv2", weights).model.state_dict())
    result = adapter.run()
    after = _pseudo_loss(adapter, _last_state(tmp_path / "adapted"))
    assert after < before
    assert result.weights.name == "best.pth"
    seg = make_segmenter("espnetv2", weights=result.weights)
    assert seg.temperature == pytest.approx(result.report["calibration"]["temperature"])
    assert seg.segment(frames[0]).labels.shape[:2] == frames[0].depth.shape
