"""The simulator's colour camera: clean is the ideal image; blur, shutter, offsets, gains, noise and JPEG behave."""

from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np
import pytest

from semmap.errors import SimulationError
from semmap.sim.camera_model import (
    ColourParams,
    apply_colour,
    colour_params,
    gains,
    sequence_twist,
    twist_between,
)
from semmap.sim.render import Renderer
from semmap.sim.scene import generate_scene
from semmap.sim.trajectory import make_trajectory
from semmap.types import DEFAULT_INTRINSICS, make_pose

SMALL = DEFAULT_INTRINSICS.scaled(0.5)
F, CX, CY = SMALL.fx, SMALL.cx, SMALL.cy
H, W = SMALL.height, SMALL.width


def _texture(seed: int = 0) -> np.ndarray:
    """Random 4-pixel blocks: sharp edges everywhere."""
    rng = np.random.default_rng(seed)
    small = rng.integers(20, 235, (H // 4, W // 4, 3), dtype=np.uint8)
    return np.ascontiguousarray(np.repeat(np.repeat(small, 4, 0), 4, 1))


def _apply(rgb, params, twist=None, frame=0, depth=2.0):
    return apply_colour(rgb, np.full((H, W), depth, np.float32), F, F, CX, CY, params, frame, twist)


def _sharpness(rgb: np.ndarray) -> float:
    return float(cv2.Laplacian(cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY), cv2.CV_64F).var())


@pytest.fixture(scope="module")
def office():
    return generate_scene(0, "office", "medium")


@pytest.fixture(scope="module")
def loop(office):
    return make_trajectory(office, "loop", 12, seed=0)


@pytest.fixture(scope="module")
def plain(office):
    return Renderer(office, SMALL, noise=True)


@pytest.mark.slow
def test_clean_render_is_unchanged(office, loop, plain):
    poses = loop
    clean = Renderer(office, SMALL, noise=True, colour=colour_params("clean"))
    for i in (0, 11):
        a = plain.render(poses[i], i)
        b = clean.render_in(poses, i)
        assert np.array_equal(a.rgb, b.rgb) and np.array_equal(a.depth, b.depth)
    rgb = _texture()
    assert _apply(rgb, ColourParams()) is rgb
    assert colour_params("clean").is_clean and not colour_params("kinect").is_clean


def test_kinect_render_changes_colour_only(office, loop, plain):
    clean = plain.render_in(loop, 6)
    real = Renderer(office, SMALL, noise=True, colour=colour_params("kinect")).render_in(loop, 6)
    assert np.array_equal(clean.depth, real.depth) and np.array_equal(clean.labels, real.labels)
    diff = np.abs(clean.rgb.astype(int) - real.rgb.astype(int))
    assert diff.mean() > 1.0
    assert abs(float(clean.rgb.mean()) - float(real.rgb.mean())) < 40  # still the same picture


def test_blur_grows_with_speed():
    rgb = _texture()
    p = ColourParams(exposure_s=0.02)
    sharp = [_sharpness(_apply(rgb, p, (np.zeros(3), np.array([0.0, w, 0.0])))) for w in (0.0, 0.3, 1.0, 3.0)]
    assert sharp[0] == pytest.approx(_sharpness(rgb))
    assert sharp[0] > sharp[1] > sharp[2] > sharp[3]
    assert sharp[3] < 0.3 * sharp[0]
    # a yaw blurs along rows, not along columns
    stripes = np.zeros((H, W, 3), np.uint8)
    stripes[(np.arange(H) // 4) % 2 == 1] = 200  # horizontal stripes: a yaw blurs along them
    yaw = (np.zeros(3), np.array([0.0, 1.0, 0.0]))
    centre = (slice(H // 2 - 40, H // 2 + 40), slice(W // 2 - 40, W // 2 + 40))
    assert np.abs(_apply(stripes, p, yaw)[centre].astype(int) - stripes[centre]).max() <= 6
    columns = np.zeros((H, W, 3), np.uint8)
    columns[:, (np.arange(W) // 4) % 2 == 1] = 200  # vertical stripes: blurred across
    assert np.abs(_apply(columns, p, yaw)[centre].astype(int) - columns[centre]).mean() > 30


def test_translation_blur_grows_for_near_surfaces():
    rgb = _texture()
    p = ColourParams(exposure_s=0.03)
    twist = (np.array([0.5, 0.0, 0.0]), np.zeros(3))
    assert _sharpness(_apply(rgb, p, twist, depth=0.5)) < 0.7 * _sharpness(_apply(rgb, p, twist, depth=5.0))


def test_rolling_shutter_slants_vertical_edges():
    rgb = np.zeros((H, W, 3), np.uint8)
    rgb[:, W // 2:] = 200
    p = ColourParams(readout_s=0.03)
    out = _apply(rgb, p, (np.zeros(3), np.array([0.0, 1.0, 0.0])))
    edge = np.argmax(out[:, :, 0] > 100, axis=1)
    # yaw to the right moves the image left; later rows (bottom) see it further left
    assert edge[5] - edge[-5] == pytest.approx(F * 1.0 * 0.03 * (H - 10) / (H - 1), abs=1.5)
    assert edge[H // 2] == pytest.approx(W // 2, abs=1)


def test_misregistration_and_time_offset_shift_the_image():
    rgb = _texture()
    out = _apply(rgb, ColourParams(offset_px=(3.0, -2.0)))
    assert np.array_equal(out[10:-10, 10:-10], rgb[8:-12, 13:-7])
    dt = 0.02
    shifted = _apply(rgb, ColourParams(time_offset_s=dt), (np.zeros(3), np.array([0.0, 0.5, 0.0])))
    # yaw 0.5 rad/s moves the centre of the image left by f * 0.5 * dt pixels after dt seconds
    s = F * 0.5 * dt
    assert np.abs(shifted[100:140, 100:140].astype(int) - rgb[100:140, 100 + round(s):140 + round(s)]).mean() < 25


def test_vignetting_darkens_corners_only():
    grey = np.full((H, W, 3), 160, np.uint8)
    out = _apply(grey, ColourParams(vignetting=0.3)).astype(float)
    assert out[H // 2, W // 2, 0] == pytest.approx(160, abs=1)
    corners = [out[0, 0, 0], out[0, -1, 0], out[-1, 0, 0], out[-1, -1, 0]]
    assert max(corners) < 0.75 * 160 and min(corners) > 0.65 * 160


def test_jpeg_changes_pixels_but_keeps_the_mean():
    rng = np.random.default_rng(1)
    rgb = cv2.GaussianBlur(rng.integers(0, 255, (H, W, 3), dtype=np.uint8), (0, 0), 1.5)
    out = _apply(rgb, ColourParams(jpeg_quality=80))
    assert not np.array_equal(out, rgb)
    assert abs(out.astype(float).mean() - rgb.astype(float).mean()) < 1.0
    worse = _apply(rgb, ColourParams(jpeg_quality=20))
    assert np.abs(worse.astype(int) - rgb).mean() > np.abs(out.astype(int) - rgb).mean()


def test_noise_grows_with_signal_and_is_seeded():
    flat = np.zeros((H, W, 3), np.uint8)
    flat[:, W // 2:] = 200
    p = ColourParams(shot_noise=0.5, read_noise=1.0, seed=3)
    a = _apply(flat, p, frame=4).astype(float)
    dark, bright = a[:, 10:W // 2 - 10].std(), a[:, W // 2 + 10:-10].std()
    assert 0.3 < dark < 1.3  # read noise only (clipped at 0)
    assert bright == pytest.approx(np.sqrt(0.5 * 200 + 1.0), rel=0.15)
    assert np.array_equal(a, _apply(flat, p, frame=4))
    assert not np.array_equal(a, _apply(flat, p, frame=5))
    assert not np.array_equal(a, _apply(flat, p.with_seed(4), frame=4))


def test_gain_drift_is_slow_reproducible_and_order_free():
    p = ColourParams(exposure_drift=0.1, white_balance_drift=0.05, seed=2)
    series = np.array([gains(p, i, 30.0) for i in range(600)])
    assert np.array_equal(gains(p, 321, 30.0), series[321])
    log_g = np.log(series)
    assert 0.03 < log_g[:, 1].std() < 0.25
    assert np.abs(np.diff(log_g, axis=0)).max() < 0.05  # slow: a few percent per frame at most
    assert not np.allclose(log_g[:, 0], log_g[:, 2])  # white balance: red and blue drift apart
    assert np.array_equal(gains(ColourParams(), 10, 30.0), np.ones(3, np.float32))


def test_auto_exposure_pulls_brightness_towards_mid_grey():
    dark = np.full((H, W, 3), 50, np.uint8)
    bright = np.full((H, W, 3), 220, np.uint8)
    p = ColourParams(auto_exposure=0.5)
    assert 50 < _apply(dark, p).mean() < 118 < _apply(bright, p).mean() < 220


def test_twist_from_poses():
    yaw = 0.3  # rad/s about camera y, and 0.5 m/s along camera x
    R = cv2.Rodrigues(np.array([0.0, yaw / 30.0, 0.0]))[0]
    poses = [make_pose(np.eye(3), [0, 0, 0])]
    for _ in range(4):
        step = make_pose(R, [0.5 / 30.0, 0, 0])
        poses.append(poses[-1] @ step)
    poses = np.stack(poses)
    v, w = twist_between(poses[0], poses[1], 1 / 30.0)
    assert v == pytest.approx([0.5, 0, 0], abs=1e-9) and w == pytest.approx([0, yaw, 0], abs=1e-9)
    v, w = sequence_twist(poses, 2, 30.0)
    assert np.linalg.norm(v) == pytest.approx(0.5, rel=1e-3) and w == pytest.approx([0, yaw, 0], abs=1e-9)


def test_bad_parameters_raise():
    with pytest.raises(SimulationError, match="does not match depth"):
        apply_colour(np.zeros((H, H, 3), np.uint8), np.ones((H, W), np.float32), F, F, CX, CY,
                     colour_params("kinect"), 0)
    with pytest.raises(SimulationError, match="preset"):
        colour_params("fancy")
    for bad in ({"exposure_s": -1.0}, {"jpeg_quality": 101}, {"vignetting": 1.0}, {"offset_px": (1.0,)},
                {"time_offset_s": float("nan")}):
        with pytest.raises(SimulationError):
            replace(ColourParams(), **bad)


def test_simulated_sequence_names_its_camera_and_hand(tmp_path):
    import json

    from semmap.sim.export import camera_info, simulate_sequence
    from semmap.sim.hand_motion import motion_params

    a = simulate_sequence(tmp_path / "a", scene_seed=2, kind="living_room", trajectory="orbit", frames=3,
                          size="small", intrinsics=SMALL, colour=colour_params("kinect", 2),
                          motion=motion_params("kinect"))
    info = json.loads((a / "scene.json").read_text())
    assert info["colour_camera"]["jpeg_quality"] == 80 and info["hand_motion"]["hand"] is True
    assert camera_info(None, None) == {}
    assert camera_info(colour_params("clean"), motion_params("clean")) == {}  # clean sequences stay as they were


def test_colour_does_not_depend_on_the_thread_count():
    import numba

    rgb = _texture(2)
    p = colour_params("hard", 1)
    twist = (np.array([0.2, 0.0, 0.1]), np.array([0.1, 0.8, 0.0]))
    before = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        one = _apply(rgb, p, twist, frame=7)
    finally:
        numba.set_num_threads(before)
    assert np.array_equal(one, _apply(rgb, p, twist, frame=7))
