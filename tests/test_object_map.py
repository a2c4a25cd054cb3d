"""The object map: outlier removal (eq. 18), association (eqs. 16-22), three sightings, merging, queries, files."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from object_helpers import OBJECT_CAMERA, box_frames
from semmap.errors import FormatError
from semmap.io.objects import read_objects_json, read_objects_ply, write_objects_json, write_objects_ply
from semmap.labels import INDOOR_LABELS
from semmap.maps._object_kernels import grid_neighbour_distances
from semmap.maps.objects import ObjectMap, ObjectMapParams, outlier_mask, overlap_iou, pack_cells, upright_box
from semmap.perception.instances.oracle import OracleInstances
from semmap.perception.tracking import DeepSort
from semmap.types import Instances

CHAIR, TABLE = INDOOR_LABELS.id_of("chair"), INDOOR_LABELS.id_of("table")
BOXES = [(np.array([-0.2, -0.8, 0.0]), np.array([0.2, -0.4, 0.8])),
         (np.array([0.8, 0.1, 0.0]), np.array([1.2, 0.5, 0.8])),
         (np.array([0.2, 0.9, 0.0]), np.array([1.2, 1.5, 0.75]))]
CLASSES = [CHAIR, CHAIR, TABLE]


def _map_run(frames, source, *, every: int = 3, params: ObjectMapParams | None = None):
    """Track every frame, integrate every ``every``-th: the map and each keyframe's object ids."""
    omap = ObjectMap(INDOOR_LABELS, params or ObjectMapParams(pixel_stride=1))
    tracker = DeepSort(num_classes=len(INDOOR_LABELS))
    assigned = []
    for f in frames:
        inst = tracker.update(source.detect(f), f, f.T_world_cam)
        if f.index % every == 0:
            assigned.append((f, inst, omap.integrate(inst, f.depth, f.rgb, f.intrinsics, f.T_world_cam, f.index)))
    return omap, assigned


@pytest.fixture(scope="module")
def arc_frames():
    return box_frames(BOXES, CLASSES, 30)


def _inside(points: np.ndarray, box, margin: float = 0.015) -> np.ndarray:
    lo, hi = box
    return np.all((points >= lo - margin) & (points <= hi + margin), axis=1)


def test_each_box_becomes_one_object_of_its_class_on_its_surface(arc_frames):
    omap, _ = _map_run(arc_frames, OracleInstances(INDOOR_LABELS, preset="exact", min_pixels=30))
    real = omap.real_objects()
    assert sorted(o.class_id for o in real) == sorted(CLASSES)
    for o in real:
        inside = [_inside(o.points, b).mean() for b in BOXES]
        assert max(inside) > 0.99  # its points lie on one box
        assert o.sightings == 10 and o.first_frame == 0 and o.last_frame == 27
    assert len(omap.objects_of_class("chair")) == 2
    near, dist = omap.nearest(np.array([1.0, 0.3, 0.4]), "chair")
    assert near is not None and _inside(near.points, BOXES[1]).all() and dist < 0.25


def test_noisy_instances_still_give_one_object_per_box(arc_frames):
    omap, _ = _map_run(arc_frames, OracleInstances(INDOOR_LABELS, preset="noisy", seed=2, min_pixels=30))
    real = omap.real_objects()
    assert sorted(o.class_id for o in real) == sorted(CLASSES)


def test_objects_need_three_sightings(arc_frames):
    omap, _ = _map_run(arc_frames[:7], OracleInstances(INDOOR_LABELS, preset="exact", min_pixels=30), every=3)
    assert omap.keyframes == 3 and len(omap.real_objects()) == 3
    short, _ = _map_run(arc_frames[:4], OracleInstances(INDOOR_LABELS, preset="exact", min_pixels=30), every=3)
    assert short.keyframes == 2 and short.real_objects() == [] and len(short.objects) == 3


def test_a_second_pass_joins_the_objects_of_the_first():
    """The boxes seen in two passes whose views overlap, the tracker reset between them (new track ids): the
    second pass's clouds join the first pass's objects through overlap and distance, not track ids."""
    source = OracleInstances(INDOOR_LABELS, preset="exact", min_pixels=30)
    omap = ObjectMap(INDOOR_LABELS, ObjectMapParams(pixel_stride=1))
    passes = (box_frames(BOXES, CLASSES, 12, arc_deg=40, start_deg=-45),
              box_frames(BOXES, CLASSES, 12, arc_deg=50, start_deg=-15))
    for p, frames in enumerate(passes):
        tracker = DeepSort(num_classes=len(INDOOR_LABELS))
        tracker._next_id = 100 * (p + 1)  # track ids never repeat
        for f in frames:
            inst = tracker.update(source.detect(f), f, f.T_world_cam)
            if f.index % 3 == 0:
                omap.integrate(inst, f.depth, f.rgb, f.intrinsics, f.T_world_cam, 100 * p + f.index)
    real = omap.real_objects()
    assert len(real) == 3 and all(o.first_frame < 100 < o.last_frame for o in real)


def test_side_by_side_objects_of_one_class_stay_apart():
    boxes = [(np.array([0.0, 0.0, 0.0]), np.array([0.3, 0.3, 0.6])),
             (np.array([0.31, 0.0, 0.0]), np.array([0.61, 0.3, 0.6]))]  # 1 cm apart, centroids 31 cm
    frames = box_frames(boxes, [CHAIR, CHAIR], 18, radius=1.8)
    omap, _ = _map_run(frames, OracleInstances(INDOOR_LABELS, preset="exact", min_pixels=30))
    assert len(omap.real_objects()) == 2


def test_outlier_removal_drops_depth_a_mask_bled_onto(arc_frames):
    f = arc_frames[0]
    ids = (f.instances == 1).astype(np.int32)
    chair = ids == 1
    ring = np.zeros_like(chair)
    for row in np.flatnonzero(chair.any(axis=1)):
        ring[row, np.flatnonzero(chair[row]).max() + 1] = True  # a 1 px seam of background given to the chair ...
    ids[ring & (f.instances == 0)] = 1
    depth = f.depth.copy()
    depth[ring & (f.instances == 0)] = depth[chair].max() + 0.8  # ... where the depth is the floor behind
    assert (ring & (f.instances == 0)).sum() > 10
    inst = Instances.from_id_image(ids, [CHAIR], [1.0])
    for k, clean in ((1.0, True), (1e6, False)):  # with eq. 18, and with a threshold nothing exceeds
        omap = ObjectMap(INDOOR_LABELS, ObjectMapParams(pixel_stride=1, sor_k=k))
        clouds = omap.extract(inst, depth, f.rgb, OBJECT_CAMERA)
        world = clouds.points @ f.T_world_cam[:3, :3].T + f.T_world_cam[:3, 3]
        assert (_inside(world, BOXES[0], 0.02).mean() > 0.995) == clean


def test_outlier_mask_is_eq_18_per_group():
    rng = np.random.default_rng(3)
    d = rng.gamma(2.0, 0.01, 400)
    groups = rng.integers(0, 3, 400)
    d[::50] = np.inf  # no neighbour at all
    kept = outlier_mask(d, groups, 3, 1.0)
    for g in range(3):
        finite = d[(groups == g) & np.isfinite(d)]
        t = finite.mean() + 1.0 * finite.std()  # t = m + k s
        sel = groups == g
        assert np.array_equal(kept[sel], np.isfinite(d[sel]) & (d[sel] <= t))


def test_grid_neighbour_distances_match_a_naive_loop():
    rng = np.random.default_rng(4)
    ids = rng.integers(0, 3, (9, 11)).astype(np.int32)
    x, y, z = (rng.random((9, 11)) for _ in range(3))
    out = grid_neighbour_distances(ids, x, y, z)
    for v in range(9):
        for u in range(11):
            if ids[v, u] == 0:
                assert np.isnan(out[v, u])
                continue
            ds = [np.sqrt((x[a, b] - x[v, u]) ** 2 + (y[a, b] - y[v, u]) ** 2 + (z[a, b] - z[v, u]) ** 2)
                  for a in range(max(v - 1, 0), min(v + 2, 9)) for b in range(max(u - 1, 0), min(u + 2, 11))
                  if (a, b) != (v, u) and ids[a, b] == ids[v, u]]
            assert out[v, u] == (pytest.approx(np.mean(ds)) if ds else np.inf)


def test_eq_22_score_needs_more_than_a_close_centroid():
    omap = ObjectMap(INDOOR_LABELS)
    k = omap.params.score_threshold
    assert omap.score(False, 0.0, 0.0) < k  # two books side by side: close centroids alone do not make one object
    assert omap.score(False, 0.2, 0.8) > k  # the paper's overlap criterion alone does
    assert omap.score(True, 0.05, 0.1) > k
    assert omap.score(True, 0.5, 0.0) > omap.score(False, 0.5, 0.0)
    a = np.unique(pack_cells(np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0]])))
    b = np.unique(pack_cells(np.array([[1, 0, 0], [2, 0, 0], [3, 0, 0]])))
    assert overlap_iou(a, b) == pytest.approx(2 / 4)  # eq. 21


@settings(max_examples=30, deadline=None)
@given(st.floats(0, 2 * np.pi), st.floats(0.05, 2.0), st.floats(0.05, 1.0), st.floats(0.05, 1.5))
def test_upright_box_holds_its_points_and_stands_on_up(yaw, a, b, c):
    rng = np.random.default_rng(0)
    local = rng.uniform(-0.5, 0.5, (200, 3)) * [a, b, c]
    R = np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]])
    pts = local @ R.T + [1.0, 2.0, 0.5]
    box = upright_box(pts, np.array([0.0, 0.0, 1.0]))
    assert np.allclose(box.rotation.T @ box.rotation, np.eye(3), atol=1e-9)
    assert np.allclose(box.rotation[:, 2], [0, 0, 1])
    inner = (pts - box.center) @ box.rotation
    assert np.all(np.abs(inner) <= box.extent / 2 + 1e-9)
    assert np.prod(box.extent) <= a * b * c * 1.02 + 1e-9  # tight: no bigger than the true box, whatever the heading


def test_object_files_round_trip(arc_frames, tmp_path):
    omap, _ = _map_run(arc_frames[:10], OracleInstances(INDOOR_LABELS, preset="exact", min_pixels=30))
    real = omap.real_objects()
    up = np.array([0.0, 0.0, 1.0])
    write_objects_json(tmp_path / "objects.json", real, INDOOR_LABELS, up)
    records = read_objects_json(tmp_path / "objects.json")
    assert [r["id"] for r in records] == [o.id for o in real]
    for r, o in zip(records, real, strict=True):
        assert r["class"] == INDOOR_LABELS.names[o.class_id] and r["points"] == len(o)
        assert np.allclose(r["centroid"], o.centroid, atol=1e-6) and r["sightings"] == o.sightings
    write_objects_ply(tmp_path / "objects.ply", real)
    ply = read_objects_ply(tmp_path / "objects.ply")
    assert len(ply["points"]) == sum(len(o) for o in real)
    for o in real:
        sel = ply["object"] == o.id
        assert np.array_equal(ply["points"][sel], o.points) and np.all(ply["label"][sel] == o.class_id)
        assert len(np.unique(ply["colors"][sel], axis=0)) == 1
    (tmp_path / "bad.json").write_text(json.dumps({"format": "semmap-objects", "objects": [{"id": 1}]}))
    with pytest.raises(FormatError, match="object 0"):
        read_objects_json(tmp_path / "bad.json")
    (tmp_path / "cut.ply").write_bytes((tmp_path / "objects.ply").read_bytes()[:-5])
    with pytest.raises(FormatError, match="truncated"):
        read_objects_ply(tmp_path / "cut.ply")


def test_the_keyframes_masks_keep_a_book_from_joining_its_missed_neighbour():
    """Two books 5 mm apart; the first keyframe's detector finds only the left one, the second only the right one
    (the left missed): the clouds alone (close centroids, shared 3 cm cells) glue the right book onto the left
    one's object; the second keyframe's image sees the left book's points outside the right one's mask."""
    from object_helpers import box_frames
    from semmap.types import CameraIntrinsics

    book = INDOOR_LABELS.id_of("book")
    boxes = [(np.array([0.0, 0.0, 0.8]), np.array([0.2, 0.04, 1.05])),
             (np.array([0.0, 0.045, 0.8]), np.array([0.2, 0.085, 1.05]))]  # spines towards the camera
    cam = CameraIntrinsics(320, 240, 260.0, 260.0, 159.5, 119.5)
    frames = box_frames(boxes, [book, book], 2, radius=1.0, height=1.0, arc_deg=10, start_deg=-5, cam=cam)
    counts = {}
    for check in (False, True):
        omap = ObjectMap(INDOOR_LABELS, ObjectMapParams(pixel_stride=1, mask_check=check))
        for f, shown in zip(frames, (1, 2), strict=True):
            inst = Instances.from_id_image((f.instances == shown).astype(np.int32), [book], [1.0])
            omap.integrate(inst, f.depth, f.rgb, f.intrinsics, f.T_world_cam, f.index)
        counts[check] = len(omap.objects)
        if check:  # each object's points lie on one book
            for o in omap.objects.values():
                assert max(_inside(o.points, b, 0.01).mean() for b in boxes) > 0.95
    assert counts == {False: 1, True: 2}


def test_mask_view_counts_only_points_the_camera_sees_and_allows_the_outline_error():
    from semmap.maps.objects import MaskView
    from semmap.types import CameraIntrinsics

    cam = CameraIntrinsics(40, 30, 40.0, 40.0, 19.5, 14.5)
    depth = np.full((30, 40), 2.0, np.float32)
    depth[:, 30:] = 0.0  # a hole
    ids = np.zeros((30, 40), np.int32)
    ids[10:20, 10:20] = 1
    view = MaskView(ids, depth, cam, np.eye(4), 1)

    def at(u, v, z):  # the world point that projects to pixel (u, v) at depth z (camera = world)
        return np.array([(u - cam.cx) / cam.fx * z, (v - cam.cy) / cam.fy * z, z])

    pts = np.array([at(15, 15, 2.0), at(21, 15, 2.0), at(25, 15, 2.0),  # in the mask, 2 px beside it, 6 px away
                    at(15, 15, 3.0),  # behind the surface the depth image shows: hidden
                    at(35, 15, 2.0)])  # on a hole: not seen
    hits, seen, _ = view.masks_hit(pts, outline_px=0)
    assert seen == 3 and hits.tolist() == [2, 1]
    hits, seen, _ = view.masks_hit(pts, outline_px=2)
    assert seen == 3 and hits.tolist() == [1, 2]  # the point 2 px off the mask counts for it


def test_a_keyframe_takes_what_its_detector_missed_from_the_frames_before_it():
    """A chair detected in the first keyframe and the frames after it, missed in the second keyframe: the frames'
    latest detection joins that keyframe (two sightings, a real object); not when the option is off, not when the
    second keyframe's camera looks away (the chair is not in view, nothing was missed), and not when the keyframe
    shows it smaller than the detector's smallest mask (small, not missed)."""
    from dataclasses import replace

    from object_helpers import look_at, render_boxes

    frames = box_frames(BOXES[:1], [CHAIR], 6, arc_deg=30)

    def run(window: bool, away: bool, min_pixels: int = 150) -> ObjectMap:
        params = ObjectMapParams(pixel_stride=1, window_sightings=window, window_min_pixels=min_pixels)
        omap = ObjectMap(INDOOR_LABELS, params)
        for f in frames[:5]:
            inst = replace(Instances.from_id_image(f.instances, [CHAIR], [1.0]), track_ids=np.array([7], np.int32))
            omap.count_track_frames(inst.track_ids)
            if f.index == 0:
                omap.integrate(inst, f.depth, f.rgb, f.intrinsics, f.T_world_cam, f.index)
            else:
                omap.note(inst, f.depth, f.rgb, f.intrinsics, f.T_world_cam)
        last = frames[5]
        T = look_at(last.T_world_cam[:3, 3], 2 * last.T_world_cam[:3, 3] - BOXES[0][1]) if away else last.T_world_cam
        depth, _ = render_boxes(BOXES[:1], T)
        missed = Instances.from_id_image(np.zeros_like(last.instances), np.zeros(0, np.int32), np.zeros(0))
        omap.integrate(missed, depth, last.rgb, last.intrinsics, T, last.index)
        return omap

    found = run(True, False)
    assert found.window_sightings == 1 and len(found.real_objects()) == 1
    assert found.real_objects()[0].sightings == 2
    assert _inside(found.real_objects()[0].points, BOXES[0]).mean() > 0.99
    shown = (BOXES[0][1] - BOXES[0][0])[2] * OBJECT_CAMERA.fx / 2.2  # its height in pixels, about
    assert 20 < shown < 100
    for window, away, min_pixels in ((False, False, 150), (True, True, 150), (True, False, int(2 * shown ** 2))):
        omap = run(window, away, min_pixels)
        assert omap.window_sightings == 0 and omap.real_objects() == [] and len(omap.objects) == 1


def _chair(x: float) -> list[tuple[np.ndarray, np.ndarray]]:
    """A chair at ``x``: seat (first box), its back raised on two posts above the seat's rear edge (+y), legs."""
    parts = [((-0.22, -0.22, 0.42), (0.22, 0.22, 0.47)),  # seat
             ((-0.22, 0.17, 0.62), (0.22, 0.22, 0.95)),  # back
             ((-0.22, 0.17, 0.47), (-0.18, 0.22, 0.62)), ((0.18, 0.17, 0.47), (0.22, 0.22, 0.62)),  # posts
             *[((sx, sy, 0.0), (sx + 0.04, sy + 0.04, 0.42)) for sx in (-0.22, 0.18) for sy in (-0.22, 0.18)]]
    at = np.array([x, 0.0, 0.0])
    return [(np.array(lo) + at, np.array(hi) + at) for lo, hi in parts]


#: ``part_share`` of an object map without the part rule
NO_PARTS = 2.0


def _parts_map(boxes, classes, views, part_share: float = ObjectMapParams.part_share) -> ObjectMap:
    """An object map of boxes seen from ``views``: (start, arc in degrees of :func:`box_frames`, masks), three
    keyframes each, whose detections ``masks(instance image) -> (id image, classes)`` makes."""
    omap = ObjectMap(INDOOR_LABELS, ObjectMapParams(pixel_stride=1, part_share=part_share))
    index = 0
    for start, arc, masks in views:
        for f in box_frames(boxes, classes, 3, radius=1.4, height=1.5, arc_deg=arc, start_deg=start):
            ids, cls = masks(f.instances)
            omap.integrate(Instances.from_id_image(ids, cls, [1.0] * len(cls)), f.depth, f.rgb, f.intrinsics,
                           f.T_world_cam, index)
            index += 1
    return omap


def test_a_chair_seen_whole_and_then_cut_into_seat_and_back_is_one_chair():
    """From the front the chair is one mask; from behind, where its back hides the seat's edge, a segmenter cuts
    it into the back and the seat seen under it: two masks of one image, which alone make two objects. The back
    seen from behind lies on the whole chair's surface (a cell from its front), so it is one chair; without the
    part rule (``part_share`` above 1), two."""
    chair = _chair(0.0)
    whole = lambda inst: ((inst > 0).astype(np.int32), [CHAIR])  # noqa: E731
    cut = lambda inst: (np.where(inst == 1, 2, np.where(inst > 1, 1, 0)).astype(np.int32), [CHAIR] * 2)  # noqa: E731
    views = [(-120, 60, whole), (70, 40, cut)]  # the front, then behind (the back stands at +y)
    classes = [CHAIR] * len(chair)
    one = _parts_map(chair, classes, views)
    assert len(one.real_objects()) == 1 and one.parts_merged >= 1
    assert len(_parts_map(chair, classes, views, NO_PARTS).real_objects()) == 2


def test_a_table_seen_from_its_two_ends_is_one_table():
    """A table seen from one end, then from the other: each side's cloud holds the near half of the top, its own
    face and legs; they share few 3 cm cells and their centroids lie 30 cm apart, so eq. 22 keeps two tables.
    Where their bounds overlap, the two tops lie on each other: one table."""
    table = [(np.array([-0.7, 0.3, 0.0]), np.array([0.7, 1.1, 0.75]))]
    whole = lambda inst: ((inst > 0).astype(np.int32), [TABLE])  # noqa: E731
    views = [(-100, 20, whole), (70, 40, whole)]
    assert len(_parts_map(table, [TABLE], views).real_objects()) == 1
    assert len(_parts_map(table, [TABLE], views, NO_PARTS).real_objects()) == 2


def test_two_chairs_side_by_side_stay_two_chairs():
    """Two chairs 6 cm apart, each its own mask in every image, seen from the front and then from behind: two
    chairs, each seen from both sides (its sides' clouds lie a cell or so apart, share few cells and have
    centroids 16 cm apart: without the part rule, four objects), and the neighbours not one."""
    chairs = _chair(0.0) + _chair(0.5)
    n = len(chairs) // 2
    apart = lambda inst: (np.where(inst > n, 2, (inst > 0).astype(np.int32)).astype(np.int32), [CHAIR] * 2)  # noqa: E731
    views = [(-120, 60, apart), (60, 60, apart)]
    omap = _parts_map(chairs, [CHAIR] * len(chairs), views)
    assert len(omap.real_objects()) == 2
    for o in omap.real_objects():  # each on one chair
        assert max(_inside(o.points, (lo, hi), 0.02).mean() for lo, hi in [(np.array([x - 0.22, -0.22, 0.0]),
                   np.array([x + 0.22, 0.22, 0.95])) for x in (0.0, 0.5)]) > 0.99
    assert len(_parts_map(chairs, [CHAIR] * len(chairs), views, NO_PARTS).real_objects()) == 4


def test_a_table_a_person_cuts_in_two_is_one_table_with_components():
    """A person standing in front of a table, seen from the front: the table's class region falls into two
    pieces, one either side. Connected components join them across the nearer person (the top continues at
    one depth): one table in the map; without joining, two."""
    from semmap.perception.instances.components import ComponentInstances
    from semmap.types import TopKProbs

    person_class = INDOOR_LABELS.id_of("person")
    boxes = [(np.array([-0.7, 0.3, 0.0]), np.array([0.7, 1.1, 0.75])),
             (np.array([-0.22, 0.0, 0.0]), np.array([0.22, 0.25, 1.8]))]
    frames = box_frames(boxes, [TABLE, person_class], 6, radius=1.4, height=1.5, arc_deg=20, start_deg=-100)
    tables = {}
    for join in (True, False):
        source = ComponentInstances(INDOOR_LABELS, join=join)
        omap = ObjectMap(INDOOR_LABELS, ObjectMapParams(pixel_stride=1))
        for f in frames:
            found = source.detect(f, TopKProbs.from_hard_labels(f.labels, 0.9, len(INDOOR_LABELS)))
            omap.integrate(found, f.depth, f.rgb, f.intrinsics, f.T_world_cam, f.index)
        tables[join] = len(omap.objects_of_class("table"))
        assert len(omap.objects_of_class("person")) == 1
    assert tables == {True: 1, False: 2}


def test_segmentation_truth_counts_split_and_merged_instances():
    """Over- and under-segmentation against ground truth: instance 1 seen as two map objects (its halves, in two
    keyframes), objects 3 and 4 glued by a merge that covers instances 2 and 3, instance 4 a stray quarter."""
    from semmap.eval.objects import SegmentationTruth

    gt = np.zeros((10, 20), np.int64)
    gt[:, :5], gt[:, 5:10], gt[:, 10:15], gt[:, 15:] = 1, 2, 3, 4
    truth = SegmentationTruth()
    det = np.zeros((10, 20), np.int32)
    det[:, :3], det[:, 5:10] = 1, 2  # keyframe 1: left of instance 1 -> object 1, instance 2 -> object 3
    truth.add_keyframe(np.array([1, 3]), det, gt)
    det[:] = 0
    det[:, 3:5], det[:, 10:15], det[:, 15:16] = 1, 2, 2  # keyframe 2: right of 1 -> object 2, 3 (+ a bit of 4) -> 4
    truth.add_keyframe(np.array([2, 4]), det, gt)
    found = truth.scores([1, 2, 3], lambda i: 3 if i == 4 else i)  # object 4 was merged into 3
    assert found["over_instances"] == [1] and found["under_objects"] == [3]
    assert found["instances_covered"] == 3 and found["over_segmented"] == 1 and found["under_segmented"] == 1
