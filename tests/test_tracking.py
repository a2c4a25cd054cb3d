"""DeepSORT: the Kalman filter's equations, the matching cascade and the track life cycle, identity switches."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from semmap.eval.objects import IdentitySwitches, detection_truth
from semmap.perception.tracking import DeepSort, DeepSortParams, TrackState, kalman
from semmap.perception.tracking.deepsort import box_iou
from semmap.types import CameraIntrinsics, Frame, Instances, make_pose

CAM = CameraIntrinsics(200, 150, 150.0, 150.0, 99.5, 74.5)


def _frame(ids: np.ndarray, colours: dict[int, tuple[int, int, int]], index: int = 0) -> Frame:
    rgb = np.zeros((*ids.shape, 3), np.uint8)
    for k, c in colours.items():
        rgb[ids == k] = c
    return Frame(index, index / 30, rgb, np.full(ids.shape, 2.0, np.float32), CAM, name=str(index))


def _boxes_frame(boxes: list[tuple[int, int, int, int]]) -> np.ndarray:
    ids = np.zeros((150, 200), np.int32)
    for k, (u0, v0, u1, v1) in enumerate(boxes, 1):
        ids[max(v0, 0):max(v1, 0), max(u0, 0):max(u1, 0)] = k
    return ids


@settings(max_examples=25, deadline=None)
@given(st.lists(st.floats(5, 100), min_size=4, max_size=4), st.floats(10, 80))
def test_kalman_steps_follow_eqs_1_to_7(z, h):
    z = np.array([z[0], z[1], 0.5 + z[2] / 100, h])
    mean, cov = kalman.initiate(z[None])
    m1, P1 = kalman.predict(mean, cov)
    A = np.eye(8)
    A[:4, 4:] = np.eye(4)
    assert np.allclose(m1[0], A @ mean[0])  # eq. 1
    assert np.allclose(P1[0] - A @ cov[0] @ A.T, np.diag(np.diag(P1[0] - A @ cov[0] @ A.T)))  # eq. 2, Q diagonal
    zk = z + np.array([1.0, -2.0, 0.01, 0.5])
    m2, P2 = kalman.update(m1, P1, zk[None])
    H = np.eye(4, 8)
    _, S = kalman.project(m1, P1)
    K = P1[0] @ H.T @ np.linalg.inv(S[0])  # eq. 5
    assert np.allclose(m2[0], m1[0] + K @ (zk - H @ m1[0]))  # eqs. 3 and 6
    assert np.allclose(P2[0], (np.eye(8) - K @ H) @ P1[0], atol=1e-9)  # eq. 7
    d2 = kalman.gating_distance(m1, P1, zk[None])
    y = zk - H @ m1[0]
    assert np.isclose(d2[0, 0], y @ np.linalg.inv(S[0]) @ y)


def test_box_iou_and_measurement_round_trip():
    a = np.array([[0, 0, 9, 9]])
    b = np.array([[5, 0, 14, 9], [20, 20, 29, 29]])
    assert np.allclose(box_iou(a, b), [[50 / 150, 0.0]])
    boxes = np.array([[3.0, 4.0, 20.0, 40.0]])
    assert np.allclose(kalman.measurements_to_boxes(kalman.boxes_to_measurements(boxes)), boxes)


def test_tracks_keep_their_ids_through_motion_and_short_misses():
    tracker = DeepSort(num_classes=3)
    colours = {1: (200, 30, 30), 2: (30, 30, 200)}
    seen: dict[int, set[int]] = {1: set(), 2: set()}
    for i in range(30):
        boxes = [(20 + 2 * i, 30, 50 + 2 * i, 80), (150 - 2 * i, 60, 180 - 2 * i, 120)]
        if 10 <= i < 13:  # the second object is missed for three frames
            boxes = boxes[:1]
        ids = _boxes_frame(boxes)
        inst = Instances.from_id_image(ids, [1] * len(boxes), [0.9] * len(boxes))
        out = tracker.update(inst, _frame(ids, colours, i))
        for k in range(len(boxes)):
            seen[k + 1].add(int(out.track_ids[k]))
    assert seen[1] == {1} and seen[2] == {2}
    assert {t.state for t in tracker.tracks} == {TrackState.CONFIRMED}


def test_tentative_tracks_die_on_a_miss_and_confirmed_ones_after_max_age():
    tracker = DeepSort(DeepSortParams(max_age=5), num_classes=2)
    one = _boxes_frame([(10, 10, 40, 40)])
    none = np.zeros_like(one)
    inst = Instances.from_id_image(one, [1], [0.9])
    tracker.update(inst, _frame(one, {1: (255, 0, 0)}))
    tracker.update(Instances.from_id_image(none, [], []), _frame(none, {}))
    assert tracker.tracks == []  # tentative, missed once
    for i in range(3):
        tracker.update(inst, _frame(one, {1: (255, 0, 0)}, i))
    assert tracker.confirmed_ids() == [2]
    for i in range(6):
        tracker.update(Instances.from_id_image(none, [], []), _frame(none, {}, i))
    assert tracker.tracks == []
    low = Instances.from_id_image(one, [1], [0.1])  # below min_score: not tracked
    assert tracker.update(low, _frame(one, {1: (255, 0, 0)})).track_ids.tolist() == [0]


def _turning_camera_ids(compensate: bool) -> list[int]:
    """Track ids each of six look-alike objects got while the camera turned 4 degrees per frame (objects jump
    10 px a frame, half their spacing); with or without the frames' poses."""
    rng = np.random.default_rng(0)
    pts = np.column_stack([np.linspace(-0.8, 0.8, 6), rng.uniform(-0.3, 0.3, 6), np.full(6, 2.0)])
    grey = {k: (128, 128, 128) for k in range(1, 7)}  # appearance cannot tell them apart
    tracker = DeepSort(num_classes=2)
    ids_of: dict[int, set[int]] = {k: set() for k in range(6)}
    for i in range(12):
        a = np.radians(4.0 * i)
        R = np.array([[np.cos(a), 0, np.sin(a)], [0, 1, 0], [-np.sin(a), 0, np.cos(a)]])
        cam = pts @ R  # world -> camera (R^T p)
        u = CAM.fx * cam[:, 0] / cam[:, 2] + CAM.cx
        v = CAM.fy * cam[:, 1] / cam[:, 2] + CAM.cy
        ids = _boxes_frame([(int(x) - 6, int(y) - 8, int(x) + 6, int(y) + 8) for x, y in zip(u, v, strict=True)])
        present = [k for k in range(6) if (ids == k + 1).any()]
        out = tracker.update(Instances.from_id_image(ids, [1] * 6, [0.9] * 6), _frame(ids, grey, i),
                             make_pose(R, [0, 0, 0]) if compensate else None)
        for j, k in enumerate(present):
            ids_of[k].add(int(out.track_ids[j]))
    return [len(v) for v in ids_of.values()]


def test_camera_motion_compensation_follows_a_turning_camera():
    assert _turning_camera_ids(True) == [1] * 6
    assert max(_turning_camera_ids(False)) > 2  # the plain constant-velocity filter loses them


def test_identity_switches_count_changes_of_a_ground_truth_objects_track():
    sw = IdentitySwitches()
    sw.add(np.array([1, 2]), np.array([10, 20]), np.array([50, 50]))
    sw.add(np.array([1, 3]), np.array([10, 20]), np.array([50, 50]))  # object 20 switched to track 3
    sw.add(np.array([1, 4]), np.array([10, 10]), np.array([50, 10]))  # a fragment of 10: the larger one counts
    assert sw.switches == 1 and sw.matched == 5
    ids = np.array([[1, 1, 2], [0, 2, 2]])
    gt = np.array([[7, 7, 7], [0, 8, 8]])
    truth, cover = detection_truth(ids, gt, 2)
    assert truth.tolist() == [7, 8] and cover.tolist() == [2, 2]
