"""Instance sources: the oracle's error model, connected components of a segmentation, Mask R-CNN on the CPU."""

from __future__ import annotations

import importlib.util

import numpy as np
import pytest

from semmap.errors import ConfigError, DatasetError
from semmap.labels import INDOOR_LABELS
from semmap.perception.instances import make_instance_source, thing_classes
from semmap.perception.instances.components import components
from semmap.perception.instances.oracle import OracleInstances
from semmap.types import CameraIntrinsics, Frame, Instances, LabelSet, TopKProbs, mask_boxes

CAM = CameraIntrinsics(160, 120, 130.0, 130.0, 79.5, 59.5)
CHAIR, TABLE, BOOK, WALL, LAMP = (INDOOR_LABELS.id_of(n) for n in ("chair", "table", "book", "wall", "lamp"))


def _scene_frame(index: int = 0, shift: int = 0) -> Frame:
    """A wall with a table, two chairs and a row of touching books (instances 1..7), 2 m away."""
    labels = np.full((120, 160), WALL, np.uint16)
    inst = np.zeros((120, 160), np.int32)
    rects = [(1, TABLE, 60, 100, 30, 110), (2, CHAIR, 70, 115, 5, 28), (3, CHAIR, 70, 115, 125, 155)]
    rects += [(4 + i, BOOK, 10, 40, 40 + 12 * i + shift, 52 + 12 * i + shift) for i in range(4)]
    for k, cls, v0, v1, u0, u1 in rects:
        labels[v0:v1, u0:u1] = cls
        inst[v0:v1, u0:u1] = k
    depth = np.full((120, 160), 2.0, np.float32)
    rgb = np.zeros((120, 160, 3), np.uint8)
    rgb[..., 0] = (inst * 37) % 256
    return Frame(index, index / 30, rgb, depth, CAM, np.eye(4), labels=labels, instances=inst, name=str(index))


def test_exact_oracle_reports_every_instance_with_its_class():
    found = OracleInstances(INDOOR_LABELS, preset="exact", min_pixels=50).detect(_scene_frame())
    assert len(found) == 7
    assert sorted(found.class_ids.tolist()) == sorted([TABLE, CHAIR, CHAIR, BOOK, BOOK, BOOK, BOOK])
    assert np.all(found.scores == 1.0)
    # each mask is exactly one ground-truth instance
    gt = _scene_frame().instances
    for k in range(1, len(found) + 1):
        assert len(np.unique(gt[found.ids == k])) == 1


def test_oracle_with_no_object_in_view_finds_none():
    """A frame of bare wall (no instance of an object class) gives no detection under any preset, not an error."""
    bare = _scene_frame()
    bare = Frame(0, 0.0, bare.rgb, bare.depth, CAM, np.eye(4), labels=np.full((120, 160), WALL, np.uint16),
                 instances=np.zeros((120, 160), np.int32), name="0")
    for preset in ("exact", "maskrcnn-like"):
        assert len(OracleInstances(INDOOR_LABELS, preset=preset).detect(bare)) == 0


def test_oracle_is_deterministic_per_seed_and_frame():
    a = OracleInstances(INDOOR_LABELS, preset="noisy", seed=3).detect(_scene_frame(5))
    b = OracleInstances(INDOOR_LABELS, preset="noisy", seed=3).detect(_scene_frame(5))
    c = OracleInstances(INDOOR_LABELS, preset="noisy", seed=4).detect(_scene_frame(5))
    assert np.array_equal(a.ids, b.ids) and np.array_equal(a.class_ids, b.class_ids)
    assert not (np.array_equal(a.ids, c.ids) and np.array_equal(a.class_ids, c.class_ids))


def test_oracle_errors_happen_at_about_their_rates():
    src = OracleInstances(INDOOR_LABELS, preset="exact", min_pixels=50, miss_p=0.3)
    counts = [len(src.detect(_scene_frame(i))) for i in range(200)]
    assert 0.62 < np.mean(counts) / 7 < 0.78  # 30 % missed
    wrong = OracleInstances(INDOOR_LABELS, preset="exact", min_pixels=50, wrong_class_p=0.5)
    classes = np.concatenate([wrong.detect(_scene_frame(i)).class_ids for i in range(100)])
    sofa = INDOOR_LABELS.id_of("sofa")
    assert (classes == sofa).any()  # chairs are mistaken for sofas (the paper's teddy bear as a person)
    split = OracleInstances(INDOOR_LABELS, preset="exact", min_pixels=50, split_p=0.5)
    assert np.mean([len(split.detect(_scene_frame(i))) for i in range(50)]) > 8


def test_oracle_merges_touching_neighbours_of_one_class_only():
    src = OracleInstances(INDOOR_LABELS, preset="exact", min_pixels=50, merge_p=1.0)
    found = src.detect(_scene_frame())
    assert len(found) == 4  # the four touching books became one mask; table and chairs stay
    assert (found.class_ids == BOOK).sum() == 1


def test_oracle_outlines_move_by_at_most_the_setting():
    frame = _scene_frame()
    src = OracleInstances(INDOOR_LABELS, preset="exact", min_pixels=50, boundary_px=2)
    for i in range(10):
        found = src.detect(frame.with_(index=i))
        area = found.pixel_counts.sum()
        assert abs(int(area) - int((frame.instances > 0).sum())) < 0.4 * (frame.instances > 0).sum()


def test_oracle_needs_instance_images_and_known_presets():
    with pytest.raises(ConfigError):
        OracleInstances(INDOOR_LABELS, preset="perfect")
    with pytest.raises(ConfigError):
        OracleInstances(INDOOR_LABELS, miss_rate=0.1)
    with pytest.raises(DatasetError):
        OracleInstances(INDOOR_LABELS).detect(_scene_frame().with_(instances=None))


def test_components_split_one_class_at_depth_jumps_and_class_changes():
    labels = np.zeros((60, 80), np.int64)
    labels[10:50, 5:35] = CHAIR
    labels[10:50, 35:75] = CHAIR  # touching the first chair in the class image ...
    depth = np.full((60, 80), 2.0, np.float32)
    depth[10:50, 35:75] = 2.6  # ... but 60 cm further back
    labels[52:58, 5:8] = CHAIR  # too small
    labels[0:8, :] = WALL  # stuff, never an instance
    conf = np.full((60, 80), 0.8, np.float32)
    found = components(labels, conf, depth, thing_classes(INDOOR_LABELS), min_pixels=50)
    assert len(found) == 2 and np.all(found.class_ids == CHAIR)
    assert np.allclose(found.scores, 0.8)
    same_depth = components(labels, conf, np.full((60, 80), 2.0, np.float32), thing_classes(INDOOR_LABELS),
                            min_pixels=50)
    assert len(same_depth) == 1


def _join(labels: np.ndarray, depth: np.ndarray, join: bool = True) -> Instances:
    """Components of a 60 x 80 class image (confidence 0.8) with or without joining parts across occluders."""
    return components(labels, np.full(labels.shape, 0.8, np.float32), depth, thing_classes(INDOOR_LABELS),
                      min_pixels=20, join_focal_px=70.0 if join else None)


def test_components_join_a_table_an_occluder_cuts_in_two():
    """A table top 2 m away seen on both sides of a chair's back 80 cm nearer, and between the back's slats:
    one table, the chair apart; without joining, the table falls into pieces."""
    labels = np.full((60, 80), WALL, np.int64)
    depth = np.full((60, 80), 3.0, np.float32)
    labels[25:45, 5:75], depth[25:45, 5:75] = TABLE, 2.0
    labels[10:55, 30:50], depth[10:55, 30:50] = CHAIR, 1.2  # the chair's back in front of the table ...
    for u in (35, 40, 45):  # ... with gaps between its slats that show the table behind it
        labels[28:40, u:u + 2], depth[28:40, u:u + 2] = TABLE, 2.0
    found = _join(labels, depth)
    assert sorted(found.class_ids.tolist()) == sorted([TABLE, CHAIR])
    table = found.ids == 1 + int(np.flatnonzero(found.class_ids == TABLE)[0])
    assert table[30, 10] and table[30, 70] and table[30, 35]  # left, right and between the slats
    assert (_join(labels, depth, join=False).class_ids == TABLE).sum() >= 2


def test_components_keep_two_chairs_apart_where_the_wall_shows_between_them():
    """Two chairs 2.5 m away behind a lamp post that hides the space between their seats: above the post the
    wall shows between them, so they stay two chairs; chairs with the floor between them, or one directly in
    front of the other, are two as well."""
    labels = np.full((60, 80), WALL, np.int64)
    depth = np.full((60, 80), 3.5, np.float32)
    labels[5:55, 10:37], depth[5:55, 10:37] = CHAIR, 2.5
    labels[5:55, 43:70], depth[5:55, 43:70] = CHAIR, 2.5
    labels[25:60, 36:44], depth[25:60, 36:44] = LAMP, 1.5
    found = _join(labels, depth)
    assert (found.class_ids == CHAIR).sum() == 2
    depth[25:60, 36:44] = 3.5  # no post: the floor shows between them all the way
    labels[25:60, 36:44] = INDOOR_LABELS.id_of("floor")
    assert (_join(labels, depth).class_ids == CHAIR).sum() == 2
    touching = np.full((60, 80), WALL, np.int64)
    touching[10:50, 5:75] = CHAIR
    near = np.full((60, 80), 2.0, np.float32)
    near[10:50, 40:75] = 2.6  # the second chair touches the first in the image, 60 cm behind it
    assert len(_join(touching, near)) == 2


def test_components_source_reuses_the_runs_semantics():
    class Never:
        name = "never"
        label_set = INDOOR_LABELS

        def segment(self, frame):
            raise AssertionError("the segmenter must not run when semantics are given")

    frame = _scene_frame()
    sem = TopKProbs.from_hard_labels(frame.labels, 0.9, len(INDOOR_LABELS))
    found = make_instance_source("components", segmenter=Never()).detect(frame, sem)
    assert len(found) == 4  # table, two chairs; the touching books of one depth are one component
    with pytest.raises(ConfigError):
        make_instance_source("components")
    with pytest.raises(ConfigError, match="no segmenter"):
        make_instance_source("components", label_set=INDOOR_LABELS).detect(frame)


def test_instances_from_id_image_renumbers_and_measures_boxes():
    ids = np.zeros((5, 6), np.int32)
    ids[1:3, 2:5] = 1
    ids[4, 0] = 3
    found = Instances.from_id_image(ids, [4, 5, 6], [0.9, 0.8, 0.7])
    assert found.class_ids.tolist() == [4, 6] and found.ids.max() == 2
    assert found.boxes.tolist() == [[2, 1, 4, 2], [0, 4, 0, 4]]
    rng = np.random.default_rng(0)
    ids = rng.integers(0, 5, (30, 40)).astype(np.int32)
    boxes, present = mask_boxes(ids, 6)
    for k in range(1, 7):
        v, u = np.nonzero(ids == k)
        assert present[k - 1] == (len(v) > 0)
        if len(v):
            assert boxes[k - 1].tolist() == [u.min(), v.min(), u.max(), v.max()]


def test_unknown_instance_source_is_a_clear_error():
    with pytest.raises(ConfigError, match="unknown instance source"):
        make_instance_source("yolo")
    with pytest.raises(ConfigError, match="--instance-weights"):
        make_instance_source("maskrcnn")


# ---------------------------------------------------------------------------------------------- Mask R-CNN
def test_pure_torch_nms_matches_the_greedy_definition():
    torch = pytest.importorskip("torch")
    from semmap.perception.instances._torchvision_ops import nms

    rng = np.random.default_rng(1)
    xy = rng.uniform(0, 50, (60, 2))
    boxes = np.concatenate([xy, xy + rng.uniform(5, 20, (60, 2))], axis=1)
    scores = rng.random(60)
    kept = nms(torch.tensor(boxes), torch.tensor(scores), 0.4).tolist()
    order, keep = np.argsort(-scores, kind="stable"), []
    for i in order:
        if all(_iou(boxes[i], boxes[j]) <= 0.4 for j in keep):
            keep.append(i)
    assert kept == keep


def _iou(a, b) -> float:
    w = max(0.0, min(a[2], b[2]) - max(a[0], b[0]))
    h = max(0.0, min(a[3], b[3]) - max(a[1], b[1]))
    inter = w * h
    return inter / ((a[2] - a[0]) * (a[3] - a[1]) + (b[2] - b[0]) * (b[3] - b[1]) - inter)


@pytest.mark.slow
@pytest.mark.skipif(importlib.util.find_spec("torchvision") is None, reason="torchvision is not installed")
def test_maskrcnn_runs_on_the_cpu_with_random_weights(tmp_path):
    import torch

    from semmap.perception.instances.maskrcnn import MaskRcnnInstances, build_maskrcnn

    torch.manual_seed(0)
    model = build_maskrcnn(4, min_size=120, max_size=160, rpn_pre_nms_top_n_test=100, rpn_post_nms_top_n_test=30,
                           box_detections_per_img=8)
    labels = LabelSet(("unknown", "a", "b", "c"), np.array([[0, 0, 0], [200, 0, 0], [0, 200, 0], [0, 0, 200]]))
    source = MaskRcnnInstances(model, labels, score_threshold=0.0)
    frame = _scene_frame()
    found = source.detect(frame)
    assert found.ids.shape == frame.depth.shape and found.ids.max() <= len(found)
    assert len(found) > 0 and found.features is not None and found.features.shape == (len(found), 1024)
    assert np.allclose(np.linalg.norm(found.features, axis=1), 1.0, atol=1e-4)
    assert np.all(np.diff(found.scores) <= 0)  # pasted most confident first
    with pytest.raises(ConfigError, match="classes"):
        MaskRcnnInstances(model, INDOOR_LABELS)
    bad = tmp_path / "weights.pth"
    torch.save({"something": torch.zeros(3)}, bad)
    with pytest.raises(ConfigError, match="not a Mask R-CNN state dict"):
        MaskRcnnInstances.from_weights(bad)
    (tmp_path / "junk.pth").write_bytes(b"not a torch file")
    with pytest.raises(ConfigError, match="cannot read"):
        MaskRcnnInstances.from_weights(tmp_path / "junk.pth")
