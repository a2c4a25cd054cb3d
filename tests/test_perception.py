"""The segmenter interface: network wrapper contracts, precomputed predictions, scheduling, and eqs. 11-12."""

from __future__ import annotations

import json
import logging

import numpy as np
import pytest
import torch

from helpers import make_room_frames, room_label_set, run_cli, write_png
from semmap.errors import ConfigError, DatasetError, FormatError
from semmap.eval.segmentation import evaluate_label_folders, segmentation_scores
from semmap.perception.network import NetworkInput, NetworkSegmenter
from semmap.perception.precomputed import PrecomputedSegmenter
from semmap.perception.schedule import Scheduler, SegmentationSchedule, with_semantics
from semmap.types import EMPTY_LABEL, LabelSet, TopKProbs, make_pose

LABELS = LabelSet.generic(5)


class TinyNet(torch.nn.Module):
    """Logits at half the input resolution from a fixed 1x1 convolution (deterministic)."""

    def __init__(self, classes: int = 5):
        super().__init__()
        torch.manual_seed(0)
        self.conv = torch.nn.Conv2d(3, classes, 1)

    def forward(self, x):
        return self.conv(torch.nn.functional.avg_pool2d(x, 2))


@pytest.fixture(scope="module")
def rgb():
    return np.random.default_rng(0).integers(0, 256, (60, 80, 3), dtype=np.uint8)


def test_network_segmenter_contract(rgb):
    seg = NetworkSegmenter(TinyNet(), LABELS, name="tiny", net_input=NetworkInput(size=(48, 32)), k=3)
    probs = seg.probabilities(rgb)
    assert probs.shape == (60, 80, 5) and probs.dtype == np.float16
    np.testing.assert_allclose(probs.astype(np.float32).sum(-1), 1.0, atol=5e-3)
    top = seg.predict(rgb)
    assert top.labels.shape == (60, 80, 3) and top.labels.dtype == np.uint16 and top.probs.dtype == np.float32
    assert (np.diff(top.probs, axis=-1) <= 1e-7).all()  # sorted by decreasing probability
    dense = probs.astype(np.float32)
    top_dense = np.take_along_axis(dense, top.labels[..., :1].astype(np.int64), -1)[..., 0]
    np.testing.assert_allclose(top_dense, dense.max(-1), atol=1e-3)  # the top class is the most probable one
    assert seg.label_set is LABELS and seg.name == "tiny"


def test_network_batches_equal_single_frames_and_k_beyond_classes_is_padded(rgb):
    seg = NetworkSegmenter(TinyNet(2), LabelSet.generic(2), name="tiny", net_input=NetworkInput(size=(40, 30)),
                           k=3, batch_size=2)
    other = rgb[::-1].copy()
    batch = seg.predict_batch([rgb, other, rgb])
    single = seg.predict(other)
    np.testing.assert_allclose(batch[1].probs, single.probs, atol=1e-5)
    assert (batch[0].labels[..., 2] == EMPTY_LABEL).all() and (batch[0].probs[..., 2] == 0).all()


def test_onnx_backend_matches_torch(rgb, tmp_path):
    kw = dict(name="tiny", net_input=NetworkInput(size=(48, 32)), k=3)
    a = NetworkSegmenter(TinyNet(), LABELS, **kw).probabilities(rgb).astype(np.float32)
    b = NetworkSegmenter(TinyNet(), LABELS, backend="onnx", cache_dir=tmp_path, cache_key="tiny", **kw)
    np.testing.assert_allclose(b.probabilities(rgb).astype(np.float32), a, atol=2e-3)
    assert len(list(tmp_path.glob("*.onnx"))) == 1


@pytest.mark.parametrize("align_corners", [False, True])
def test_fused_resample_matches_torch_softmax_then_bilinear(align_corners):
    """Top-k from the numba kernel equals torch: softmax on the logit grid, bilinear resize, topk."""
    from semmap.perception._resample_kernels import resample_topk, sampling_map, softmax_channels_last

    logits = np.random.default_rng(1).normal(0, 3, (7, 9, 13)).astype(np.float32)
    out_h, out_w = (9 * 3, 13 * 3) if not align_corners else (17, 25)  # align_corners: image = network input
    in_h, in_w = (9, 13) if not align_corners else (17, 25)
    sy, oy = sampling_map(out_h, in_h, 9, align_corners)
    sx, ox = sampling_map(out_w, in_w, 13, align_corners)
    labels, probs = resample_topk(softmax_channels_last(logits), out_h, out_w, sy, oy, sx, ox, 3, EMPTY_LABEL)
    ref = torch.nn.functional.interpolate(torch.softmax(torch.from_numpy(logits)[None], 1), size=(out_h, out_w),
                                          mode="bilinear", align_corners=align_corners)
    ref_p, ref_i = torch.topk(ref, 3, dim=1)
    np.testing.assert_allclose(probs, ref_p[0].permute(1, 2, 0).numpy(), atol=1e-6)
    assert (labels == ref_i[0].permute(1, 2, 0).numpy()).mean() > 0.999  # ties may order differently


def test_input_keeps_the_aspect_ratio_at_the_short_side():
    assert NetworkInput().size_for(640, 480) == (512, 384)
    assert NetworkInput(short_side=200).size_for(480, 640) == (208, 272)
    assert NetworkInput(size=(384, 384)).size_for(640, 480) == (384, 384)
    with pytest.raises(ConfigError):
        NetworkInput(size=None, short_side=None)


def test_wrong_class_count_and_backend_are_clear_errors(rgb):
    with pytest.raises(ConfigError, match="backend"):
        NetworkSegmenter(TinyNet(), LABELS, name="tiny", backend="tensorrt")
    seg = NetworkSegmenter(TinyNet(4), LABELS, name="tiny", net_input=NetworkInput(size=(32, 32)))
    with pytest.raises(ConfigError, match="predicts 4 classes"):
        seg.predict(rgb)


def test_frames_with_their_colour_cameras_view_are_segmented_on_it_and_mapped_to_depth():
    """A frame whose colour was registered onto depth keeps the colour camera's own image; the network segments
    that whole view and the classes land on the depth pixels that see them."""
    from semmap.geometry import onto_depth_grid, register_color
    from semmap.types import CameraIntrinsics, ColorCamera, Frame, RawColor

    cam = CameraIntrinsics(80, 60, 73.0, 73.0, 40.0, 30.0)
    color_cam = ColorCamera(65.5, 65.5, 40.5, 29.0, (-0.03, 0.0, 0.0))
    raw = np.zeros((60, 80, 3), np.uint8)
    raw[:, 40:] = 255  # the right half of the colour camera's view is bright
    depth = np.full((60, 80), 1.2, np.float32)
    frame = Frame(0, 0.0, register_color(raw, depth, cam, color_cam), depth, cam,
                  raw_color=RawColor(raw, color_cam))
    seg = NetworkSegmenter(TinyNet(), LABELS, name="tiny", net_input=NetworkInput(size=(40, 30)), k=3)
    on_raw = seg.predict(raw)
    top = seg.segment(frame)
    assert top.labels.shape == (60, 80, 3)
    labels, probs = onto_depth_grid(frame, on_raw.labels, on_raw.probs)
    np.testing.assert_array_equal(top.labels, labels)
    np.testing.assert_array_equal(top.probs, probs)
    # where the registered colour is bright the mapped classes are the bright half's
    bright = frame.rgb[..., 0] > 200
    assert bright.any() and (~bright).any()
    assert (top.labels[..., 0][bright] == on_raw.labels[30, 70, 0]).mean() > 0.95
    assert seg.segment_batch([frame, frame])[1].labels.shape == (60, 80, 3)
    with pytest.raises(DatasetError, match="raw colour"):
        frame.with_(raw_color=RawColor(raw[..., 0], color_cam))


# ------------------------------------------------------------------ precomputed
@pytest.fixture()
def frames():
    return make_room_frames(4)


def test_precomputed_matches_by_name_and_by_timestamp(frames, tmp_path):
    h, w = frames[0].depth.shape
    ids = np.full((h, w), 3, np.uint16)
    write_png(tmp_path / f"{frames[0].name}.png", ids)  # exact name
    probs = np.zeros((h // 2, w // 2, 7), np.float32)
    probs[..., 5] = 0.7
    probs[..., 2] = 0.3
    np.save(tmp_path / f"{frames[1].timestamp + 0.004:.6f}.npy", probs)  # timestamp, other size
    (tmp_path / "labelset.json").write_text(json.dumps(room_label_set().to_dict()))
    seg = PrecomputedSegmenter(tmp_path, label_confidence=0.8)
    assert len(seg.label_set) == 7
    a = seg.segment(frames[0])
    assert (a.labels[..., 0] == 3).all() and np.allclose(a.probs[..., 0], 0.8)
    b = seg.segment(frames[1])
    assert b.labels.shape == (h, w, 3) and (b.labels[..., 0] == 5).all() and (b.labels[..., 1] == 2).all()
    np.testing.assert_allclose(b.probs[..., 0], 0.7, atol=1e-6)


def test_precomputed_missing_frame_warns_and_gives_no_semantics(frames, tmp_path, caplog):
    write_png(tmp_path / f"{frames[0].name}.label.png", np.ones(frames[0].depth.shape, np.uint16))
    seg = PrecomputedSegmenter(tmp_path, label_set=room_label_set())
    with caplog.at_level(logging.WARNING, logger="semmap"):
        assert seg.segment(frames[2]) is None
    assert seg.missing == [frames[2].name] and frames[2].name in caplog.text


def test_precomputed_bad_input_is_named(frames, tmp_path):
    with pytest.raises(ConfigError, match="does not exist"):
        PrecomputedSegmenter(tmp_path / "nope")
    with pytest.raises(ConfigError, match="no predictions"):
        PrecomputedSegmenter(tmp_path)
    np.save(tmp_path / f"{frames[0].name}.npy", np.full((*frames[0].depth.shape, 7), 0.5, np.float32))
    (tmp_path / f"{frames[1].name}.npy").write_bytes(b"garbage")
    seg = PrecomputedSegmenter(tmp_path)
    with pytest.raises(FormatError, match="apply a softmax"):
        seg.segment(frames[0])
    with pytest.raises(FormatError, match=frames[1].name):
        seg.segment(frames[1])
    write_png(tmp_path / f"{frames[2].name}.png", np.full(frames[2].depth.shape, 9, np.uint16))
    with pytest.raises(FormatError, match="outside the label set"):
        PrecomputedSegmenter(tmp_path, label_set=room_label_set()).segment(frames[2])


# ------------------------------------------------------------------ scheduling
def test_every_k_and_keyframe_schedules():
    still = np.eye(4)
    every3 = Scheduler(SegmentationSchedule(every=3))
    assert [every3.due(still) for _ in range(7)] == [True, False, False, True, False, False, True]
    key = Scheduler(SegmentationSchedule(keyframes=True, min_translation=0.1, min_rotation_deg=10))
    moved = make_pose(np.eye(3), [0.15, 0, 0])
    c, s = np.cos(np.radians(12)), np.sin(np.radians(12))
    turned = make_pose(np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]), [0.15, 0, 0])
    assert [key.due(T) for T in (still, still, moved, moved, turned)] == [True, False, True, False, True]


class CountingSegmenter:
    name = "counting"
    label_set = LABELS

    def __init__(self):
        self.batches: list[int] = []

    def segment(self, frame):
        return self.segment_batch([frame])[0]

    def segment_batch(self, frames):
        self.batches.append(len(frames))
        return [TopKProbs.from_hard_labels(np.full(f.depth.shape, 1, np.uint16), 0.9, 5) for f in frames]


def test_batched_segmentation_keeps_frame_order(frames):
    more = make_room_frames(7)
    seg = CountingSegmenter()
    timings: dict[str, float] = {}
    out = list(with_semantics(((f, f.T_world_cam) for f in more), seg, Scheduler(SegmentationSchedule(every=2)),
                              batch_size=3, timings=timings))
    assert [f.index for f, _, _ in out] == list(range(7))
    assert [sem is not None for _, _, sem in out] == [True, False, True, False, True, False, True]
    assert seg.batches == [3, 1] and timings["segment"] > 0


# ------------------------------------------------------------------ metrics (eqs. 11-12)
def test_mpa_and_miou_against_a_hand_computed_confusion_matrix():
    # p_ij: true i predicted j; 3 classes, class 0 counted (VOC background)
    conf = np.array([[5, 1, 0], [2, 6, 2], [0, 0, 4]])
    gt = np.repeat(np.repeat(np.arange(3), 3), conf.ravel())
    pred = np.repeat(np.tile(np.arange(3), 3), conf.ravel())
    s = segmentation_scores(pred, gt, 3, ignore=None)
    iou = [5 / (6 + 7 - 5), 6 / (10 + 7 - 6), 4 / (4 + 6 - 4)]
    acc = [5 / 6, 6 / 10, 4 / 4]
    np.testing.assert_allclose(s.iou, iou)
    np.testing.assert_allclose(s.class_accuracy, acc)
    assert s.miou == pytest.approx(np.mean(iou)) and s.mpa == pytest.approx(np.mean(acc))
    assert s.accuracy == pytest.approx(15 / 20)


def test_eval_folders_resize_ignore_and_report_missing(tmp_path):
    pred_dir, gt_dir = tmp_path / "pred", tmp_path / "gt"
    gt = np.zeros((4, 6), np.uint8)
    gt[:, 3:] = 1
    gt[0, 0] = 255  # VOC boundary pixel: ignored
    write_png(gt_dir / "a.png", gt)
    write_png(gt_dir / "b.png", gt)
    pred = np.zeros((2, 3), np.uint8)
    pred[:, 2] = 1  # half resolution: upsampled by nearest neighbour
    write_png(pred_dir / "a.png", pred)
    with pytest.raises(DatasetError, match=r"a\.png: prediction is 3x2, its ground truth a\.png 6x4 \(pass --resize"):
        evaluate_label_folders(pred_dir, gt_dir, 2)
    r = evaluate_label_folders(pred_dir, gt_dir, 2, resize=True)
    assert r.images == 1 and r.missing == ("b",)
    assert r.confusion.tolist() == [[11, 0], [4, 8]]  # column 3 of the upsampled prediction is class 0
    d = r.to_dict()
    assert d["per_class"]["1"]["iou"] == pytest.approx(8 / 12, abs=1e-4)
    unrelated = tmp_path / "unrelated"
    write_png(unrelated / "zzz.png", gt)
    with pytest.raises(DatasetError, match="no prediction matches"):
        evaluate_label_folders(unrelated, gt_dir, 2)


# ------------------------------------------------------------------ end to end
@pytest.mark.slow
def test_run_with_precomputed_segmentation_every_second_frame(tmp_path):
    from semmap.datasets import open_dataset
    from semmap.io.tum_writer import write_tum_sequence

    root = tmp_path / "seq"
    write_tum_sequence(root, make_room_frames(6), label_set=room_label_set())
    preds = tmp_path / "preds"
    for frame in open_dataset(root):  # predictions named like the frames, from the room's true labels
        write_png(preds / f"{frame.name}.png", frame.labels)
    (preds / "labelset.json").write_text(json.dumps(room_label_set().to_dict()))
    out = tmp_path / "out"
    r = run_cli("run", str(root), "--out", str(out), "--resolution", "0.1", "--segmenter", "precomputed",
                "--weights", str(preds), "--segment-every", "2")
    assert r.returncode == 0, r.stderr
    report = json.loads((out / "report.json").read_text())
    assert report["segmenter"] == "precomputed" and report["frames_segmented"] == 3
    assert set(report["voxels_per_class"]) <= set(room_label_set().names[1:])
    classified = sum(report["voxels_per_class"].values())
    assert classified + report["voxels_without_class"] == report["occupied_voxels"]
    assert classified > 0.5 * report["occupied_voxels"]  # voxels seen only by unsegmented frames have no class
    assert report["precomputed_miou_2d"] == 1.0  # predictions are the ground truth


@pytest.mark.slow
def test_eval_seg_command(tmp_path):
    gt = np.zeros((4, 6), np.uint8)
    gt[:, 3:] = 1
    write_png(tmp_path / "gt" / "x.png", gt)
    write_png(tmp_path / "pred" / "x.png", gt)
    r = run_cli("eval-seg", str(tmp_path / "pred"), str(tmp_path / "gt"), "--num-classes", "2", "--out",
                str(tmp_path / "s.json"), "--json")
    assert r.returncode == 0, r.stderr
    assert json.loads(r.stdout)["miou"] == 1.0 and json.loads((tmp_path / "s.json").read_text())["mpa"] == 1.0
    r = run_cli("eval-seg", str(tmp_path / "nope"), str(tmp_path / "gt"))
    assert r.returncode == 1 and "nope" in r.stderr and "Traceback" not in r.stderr


def test_a_short_last_onnx_batch_runs_padded_on_the_same_graph(rgb, tmp_path):
    # a run's last batch may hold fewer frames: it must not export and open a second graph mid-run
    seg = NetworkSegmenter(TinyNet(), LABELS, name="tiny", net_input=NetworkInput(size=(48, 32)), k=3,
                           batch_size=3, backend="onnx", cache_dir=tmp_path, cache_key="tiny")
    full = seg.predict_batch([rgb, rgb[::-1].copy(), rgb])
    short = seg.predict_batch([rgb[::-1].copy()])
    assert len(short) == 1 and len(list(tmp_path.glob("*.onnx"))) == 1
    np.testing.assert_allclose(short[0].probs, full[1].probs, atol=1e-6)


def test_prepare_pays_the_onnx_export_before_the_first_frame(tmp_path):
    from semmap.perception.base import Preparable

    frame = make_room_frames(1)[0]
    seg = NetworkSegmenter(TinyNet(), LABELS, name="tiny", net_input=NetworkInput(size=(48, 32)), k=3,
                           backend="onnx", cache_dir=tmp_path, cache_key="tiny")
    assert isinstance(seg, Preparable)
    assert seg.prepare(frame) > 0 and len(list(tmp_path.glob("*.onnx"))) == 1
    assert seg.segment(frame).labels.shape[:2] == frame.depth.shape
