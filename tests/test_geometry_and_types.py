"""Back-projection (eq. 7), voxel filter, SE(3) helpers, label sets and class-probability types."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from semmap.errors import ConfigError, DatasetError
from semmap.geometry import backproject, backproject_world, register_color, voxel_filter
from semmap.types import (
    EMPTY_LABEL,
    CameraIntrinsics,
    ColorCamera,
    LabelSet,
    TopKProbs,
    check_pose,
    interpolate_pose,
    invert_pose,
    make_pose,
    pose_change,
    pose_from_tum,
    pose_to_tum,
    quat_xyzw_to_rot,
    rotation_angle,
    transform_points,
)

CAM = CameraIntrinsics(8, 6, 5.0, 6.0, 3.5, 2.5)


def test_backprojection_follows_the_pinhole_equation():
    depth = np.zeros((6, 8), np.float32)
    depth[1, 2] = 2.0
    depth[4, 7] = 9.0  # beyond max depth
    pts, pix = backproject(depth, CAM, max_depth=8.0)
    assert pix.tolist() == [1 * 8 + 2]
    assert pts[0] == pytest.approx([2.0 * (2 - 3.5) / 5.0, 2.0 * (1 - 2.5) / 6.0, 2.0])


def test_world_backprojection_equals_camera_backprojection_then_pose():
    rng = np.random.default_rng(0)
    depth = rng.uniform(0.0, 5.0, (6, 8)).astype(np.float32)
    T = make_pose(quat_xyzw_to_rot([0.1, 0.2, 0.3, 0.9]), [1.0, -2.0, 0.5])
    pc, pix_c = backproject(depth, CAM, min_depth=0.5, max_depth=4.0, stride=2)
    pw, pix_w = backproject_world(depth, CAM, T, min_depth=0.5, max_depth=4.0, stride=2)
    assert np.array_equal(pix_c, pix_w) and pw.dtype == np.float32
    assert pw == pytest.approx(transform_points(T, pc), abs=1e-5)


def test_backprojection_rejects_mismatched_images_and_ranges():
    with pytest.raises(ConfigError, match="does not match"):
        backproject(np.zeros((5, 8), np.float32), CAM)
    with pytest.raises(ConfigError, match="depth range"):
        backproject(np.zeros((6, 8), np.float32), CAM, min_depth=3.0, max_depth=1.0)


@settings(max_examples=50, deadline=None)
@given(st.integers(1, 400), st.sampled_from([0.02, 0.1, 0.5]))
def test_voxel_filter_keeps_exactly_one_point_per_cell(n, res):
    pts = np.random.default_rng(n).uniform(-2, 2, (n, 3))
    keep = voxel_filter(pts, res)
    cells = np.floor(pts / res).astype(int)
    assert len(np.unique(cells[keep], axis=0)) == len(keep) == len(np.unique(cells, axis=0))
    assert np.all(np.diff(keep) > 0)


@settings(max_examples=100, deadline=None)
@given(st.lists(st.floats(-1, 1), min_size=4, max_size=4).filter(lambda q: np.linalg.norm(q) > 0.1),
       st.lists(st.floats(-10, 10), min_size=3, max_size=3))
def test_tum_pose_round_trip_and_inverse(q, t):
    T = pose_from_tum([*t, *q])
    assert pose_from_tum(pose_to_tum(T)) == pytest.approx(T, abs=1e-9)
    assert T @ invert_pose(T) == pytest.approx(np.eye(4), abs=1e-9)
    check_pose(T)


@settings(max_examples=100, deadline=None)
@given(st.lists(st.floats(-1, 1), min_size=3, max_size=3).filter(lambda a: np.linalg.norm(a) > 1e-3),
       st.floats(1e-6, np.pi - 1e-3))
def test_rotation_angle_is_the_axis_angle(axis, angle):
    axis = np.asarray(axis) / np.linalg.norm(axis)
    R = quat_xyzw_to_rot([*(np.sin(angle / 2) * axis), np.cos(angle / 2)])
    assert rotation_angle(R) == pytest.approx(angle, rel=1e-6, abs=1e-9)
    T = make_pose(R, [0.3, 0, 0])
    assert pose_change(np.eye(4), T) == pytest.approx((0.3, np.degrees(angle)), rel=1e-6, abs=1e-9)


def test_rotation_angle_ignores_slight_non_orthonormality():
    """7-Scenes rotations are off orthonormal by up to 3e-4; arccos of the trace would read that as ~1 degree."""
    R = np.eye(3) + np.diag([-3e-4, -3e-4, 0.0])
    assert np.degrees(rotation_angle(R)) < 1e-6
    turn = quat_xyzw_to_rot([0, 0, np.sin(0.005), np.cos(0.005)])  # 0.01 rad about z
    assert rotation_angle(turn * (1 - 3e-4)) == pytest.approx(0.01, rel=1e-3)


def test_pose_interpolation_hits_the_ends_and_the_middle():
    A = make_pose(np.eye(3), [0, 0, 0])
    B = make_pose(quat_xyzw_to_rot([0, 0, np.sin(0.5), np.cos(0.5)]), [2, 0, 0])
    assert interpolate_pose(A, B, 0.0) == pytest.approx(A)
    assert interpolate_pose(A, B, 1.0) == pytest.approx(B, abs=1e-9)
    mid = interpolate_pose(A, B, 0.5)
    assert mid[:3, 3] == pytest.approx([1, 0, 0])
    assert mid[:3, :3] == pytest.approx(quat_xyzw_to_rot([0, 0, np.sin(0.25), np.cos(0.25)]), abs=1e-9)


def test_non_finite_or_non_rigid_poses_are_errors():
    T = np.eye(4)
    T[0, 3] = np.nan
    with pytest.raises(DatasetError, match="non-finite"):
        check_pose(T, "frame 3")
    with pytest.raises(DatasetError, match="rigid"):
        check_pose(np.diag([2.0, 1, 1, 1]))


def test_label_sets_round_trip_and_never_use_white(tmp_path):
    ls = LabelSet(("unknown", "wall", "chair"), np.array([[0, 0, 0], [255, 255, 255], [10, 200, 30]]))
    assert tuple(ls.colors[1]) != (255, 255, 255)
    ls.save(tmp_path / "labels.json")
    back = LabelSet.load(tmp_path / "labels.json")
    assert back.names == ls.names and np.array_equal(back.colors, ls.colors)
    assert ls.id_of("chair") == 2
    assert ls.colorize(np.array([[2, 0]])).tolist() == [[[10, 200, 30], [0, 0, 0]]]
    generic = LabelSet.generic(40)
    assert len({tuple(c) for c in generic.colors.tolist()}) == 40


def test_top_k_from_dense_probabilities_and_hard_labels():
    probs = np.array([[[0.1, 0.6, 0.3]], [[0.5, 0.25, 0.25]]], np.float32)
    tk = TopKProbs.from_dense(probs, k=3)
    assert tk.labels[0, 0].tolist() == [1, 2, 0] and tk.labels[1, 0].tolist() == [0, 1, 2]
    assert tk.others == pytest.approx(np.zeros((2, 1)), abs=1e-6)
    hard = TopKProbs.from_hard_labels(np.array([[2, 1]]), 0.9, num_classes=3)
    assert hard.labels[0, 0].tolist() == [2, EMPTY_LABEL, EMPTY_LABEL]
    assert hard.others == pytest.approx(np.array([[0.1, 0.1]]))
    with pytest.raises(ConfigError):
        TopKProbs.from_hard_labels(np.array([[5]]), 0.9, num_classes=3)


def test_colour_registration_shows_each_depth_pixel_what_the_colour_camera_saw_there():
    """A textured wall 1.5 m away seen by a depth camera and by a colour camera with another focal length, 3 cm to
    the side: after registration the colour at every depth pixel is the wall's texture at that pixel's 3D point."""
    depth_cam = CameraIntrinsics(160, 120, 146.0, 146.0, 80.0, 60.0)
    color = ColorCamera(131.0, 131.0, 81.5, 58.0, (-0.03, 0.005, 0.0))
    z = 1.5

    def texture(x: np.ndarray, y: np.ndarray) -> np.ndarray:  # smooth, so bilinear sampling is near exact
        return (127 + 60 * np.sin(6 * x) + 60 * np.cos(5 * y)).clip(0, 255)

    v, u = np.mgrid[0:120, 0:160].astype(np.float64)
    # the colour image: each colour pixel's ray hits the wall (z = 1.5 in both frames: no rotation, tz = 0)
    xc = (u - color.cx) / color.fx * z - color.t_color_depth[0]
    yc = (v - color.cy) / color.fy * z - color.t_color_depth[1]
    rgb = np.repeat(texture(xc, yc)[..., None], 3, axis=2).astype(np.uint8)
    depth = np.full((120, 160), z, np.float32)
    depth[:5] = 0.0  # a few pixels without depth use the median depth (here exact)
    out = register_color(rgb, depth, depth_cam, color)
    want = texture((u - depth_cam.cx) / depth_cam.fx * z, (v - depth_cam.cy) / depth_cam.fy * z)
    inner = (slice(8, -8), slice(8, -8))
    assert out.shape == rgb.shape and out.dtype == np.uint8
    assert np.abs(out[..., 0][inner].astype(float) - want[inner]).max() <= 2.0
    # the unregistered image is far off: a 10% different focal length and a 3 cm baseline
    assert np.abs(rgb[..., 0][inner].astype(float) - want[inner]).mean() > 10
