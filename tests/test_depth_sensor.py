"""Depth sensor models (structured light, time of flight) and the realism presets that compose them."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from helpers import ROOM_CAMERA
from semmap.errors import SimulationError
from semmap.sim.depth_sensor import StructuredLight, TimeOfFlight, material_drop
from semmap.sim.export import simulate_frames, simulate_sequence
from semmap.sim.materials import Material
from semmap.sim.noise import KinectNoise
from semmap.sim.realism import REALISMS, realism, with_depth
from semmap.sim.scene import generate_scene
from semmap.sim.trajectory import make_trajectory

H, W, FX = 120, 160, 150.0
#: A sensor with only the axial noise and quantisation (for the statistics of a plane).
PLAIN = StructuredLight(seed=3, shadow=False, edge_drop_p=0.0, lateral_px=0.0, far_drop_p=0.0, dead_px=0,
                        min_depth=0.3, max_depth=8.0)


def _plane(z: float, shape: tuple[int, int] = (H, W)) -> tuple[np.ndarray, np.ndarray]:
    return np.full(shape, z, np.float32), np.ones(shape, np.float32)


def _error_std(sensor: StructuredLight, z: float, cos: float = 1.0) -> float:
    depth, c = _plane(z, (240, 320))
    out = sensor.apply_view(depth, c * cos, 0, fx=FX)
    ok = out > 0
    assert ok.mean() > 0.95
    return float(np.std(out[ok] - z))


@pytest.mark.slow
def test_axial_noise_grows_with_the_square_of_the_depth():
    stds = {z: _error_std(PLAIN, z) for z in (1.0, 2.0, 3.0)}
    assert 3.0 < stds[2.0] / stds[1.0] < 5.0  # 4 for z^2
    assert 7.0 < stds[3.0] / stds[1.0] < 11.5  # 9 for z^2
    for z, s in stds.items():  # noise and quantisation together, as the model's own sigma says
        expect = np.sqrt(PLAIN.axial_sigma(z) ** 2 + PLAIN.quantum(z) ** 2 / 12)
        assert s == pytest.approx(expect, rel=0.3), z


@pytest.mark.slow
def test_axial_noise_grows_with_the_angle_of_incidence():
    assert _error_std(PLAIN, 2.0, cos=np.cos(np.radians(82))) > 1.4 * _error_std(PLAIN, 2.0, cos=1.0)


def test_depth_is_quantised_to_subpixel_disparity_steps():
    depth = np.linspace(1.0, 3.5, W, dtype=np.float32)[None].repeat(H, 0)
    out = PLAIN.apply_view(depth, np.ones_like(depth), 0, fx=FX)
    d = PLAIN.focal_px * PLAIN.baseline_m / out[out > 0] * PLAIN.subpixel
    assert np.abs(d - np.round(d)).max() < 1e-3
    steps = np.unique(np.round(d))
    assert len(steps) > 50  # many levels, one step apart where the depth is dense in them
    assert np.diff(steps).min() == 1


def _box_scene() -> tuple[np.ndarray, np.ndarray]:
    """Background at 2 m with a box at 1 m in columns 60..99."""
    depth, cos = _plane(2.0)
    depth[:, 60:100] = 1.0
    return depth, cos


def test_holes_beside_discontinuities_on_the_side_away_from_the_projector():
    depth, cos = _box_scene()
    sensor, fx = StructuredLight(seed=1, dead_px=0), 600.0
    out = sensor.apply_view(depth, cos, 0, fx=fx)
    width = fx * sensor.baseline_m * (1 / 1.0 - 1 / 2.0)  # 22.5 px of shadow, less the slack
    band = int(width - sensor.shadow_slack_px)
    assert band > 15
    assert (out[:, 60 - band:58] == 0).mean() > 0.95  # left of the box: the projector (at +x) cannot see it
    assert (out[:, 102:102 + band] == 0).mean() < 0.15  # right of the box: lit
    assert (out[:, 10:35] > 0).mean() > 0.97 and (out[:, 65:95] > 0).mean() > 0.97  # flat parts keep their depth
    mirrored = dataclasses.replace(sensor, projector_side=-1).apply_view(depth, cos, 0, fx=fx)
    assert (mirrored[:, 102:100 + band] == 0).mean() > 0.95 and (mirrored[:, 60 - band:58] == 0).mean() < 0.15


def test_edges_are_ragged_and_lose_pixels():
    depth, cos = _box_scene()
    out = StructuredLight(seed=1, shadow=False, edge_drop_p=0.5, dead_px=0).apply_view(depth, cos, 0, fx=FX)
    right = out[:, 98:102]
    assert 0.1 < (right == 0).mean() < 0.6
    # lateral noise: some pixels of the background column beside the box read the box's depth and vice versa
    assert np.any(np.abs(out[:, 100] - 1.0) < 0.05) and np.any(np.abs(out[:, 99] - 2.0) < 0.1)


def test_minimum_and_maximum_range():
    sensor = StructuredLight(seed=0, dead_px=0)
    for z, valid in ((0.6, False), (4.6, False), (2.0, True)):
        depth, cos = _plane(z)
        out = sensor.apply_view(depth, cos, 0, fx=FX)
        assert ((out > 0).mean() > 0.95) == valid, z
    out = StructuredLight(seed=0).apply_view(*_plane(2.0), 0, fx=FX)
    assert (out[:, W - 8:] == 0).all() and (out[:, :W - 8] > 0).mean() > 0.95  # the dead columns on the right


def test_dark_specular_and_transparent_materials_lose_depth():
    dark, glossy = Material("paint", (10, 10, 12)), Material("metal", (160, 165, 170))
    glass = Material("sky", (0, 0, 0))
    bright = Material("paint", (225, 220, 205))
    sensor = StructuredLight(seed=2, dead_px=0)
    drops = sensor.material_dropout([bright, dark, glossy, glass])
    assert drops[0] == 0 and drops[1] > 0.3 and drops[2] > 0.2 and drops[3] > 0.9
    assert material_drop(bright, 45, 0.6, 0.3, 0.9) == 0.0
    depth, cos = _plane(2.0)
    ids = np.repeat(np.arange(4, dtype=np.int32), W // 4)[None].repeat(H, 0)
    out = sensor.apply_view(depth, cos, 0, fx=FX, tri_ids=ids.reshape(-1), tri_drop=drops)
    lost = [(out[ids == k] == 0).mean() for k in range(4)]
    assert lost[0] < 0.02 and lost[3] > 0.85 and lost[0] < lost[2] < lost[1] < lost[3]


def test_same_seed_and_frame_same_depth_else_different():
    depth, cos = _box_scene()
    a = StructuredLight(seed=4).apply_view(depth, cos, 7, fx=FX)
    assert np.array_equal(a, StructuredLight(seed=4).apply_view(depth, cos, 7, fx=FX))
    assert not np.array_equal(a, StructuredLight(seed=4).apply_view(depth, cos, 8, fx=FX))
    assert not np.array_equal(a, StructuredLight(seed=5).apply_view(depth, cos, 7, fx=FX))


def test_time_of_flight_flying_pixels_and_multipath():
    depth, cos = _box_scene()
    tof = TimeOfFlight(seed=1, sigma0=0.0, sigma1=0.0)
    out = tof.apply_view(depth, cos, 0, fx=FX)
    edge = out[:, [59, 60, 99, 100]]
    assert np.any((edge > 1.05) & (edge < 1.95))  # flying pixels between the two surfaces
    flat = out[:, 20:40]
    assert np.abs(flat - 2.0).max() < 1e-4
    # a corner seen from inside (a V in depth) reads deeper than it is near its apex
    u = np.arange(W, dtype=np.float32)
    corner = (3.0 - 0.01 * np.abs(u - W / 2))[None].repeat(H, 0)
    bias = tof.apply_view(corner, np.ones_like(corner), 0, fx=FX) - corner
    assert bias[:, W // 2].mean() > 0.005 and abs(bias[:, 20:30].mean()) < 1e-3
    with pytest.raises(SimulationError):
        TimeOfFlight(multipath_px=4)


def test_presets_clean_is_todays_noise_and_others_differ():
    assert REALISMS[0] == "clean" and set(REALISMS) == {"clean", "kinect", "hard"}
    assert realism("clean").depth_model(5) == KinectNoise(seed=5)
    assert realism("clean").depth_model(5, noise=False) is None
    assert isinstance(realism("kinect").depth_model(5), StructuredLight)
    hard, kinect = realism("hard").depth, realism("kinect").depth
    assert hard.sigma_disp_px > kinect.sigma_disp_px
    assert with_depth(realism("kinect"), TimeOfFlight()).depth == TimeOfFlight()
    with pytest.raises(SimulationError, match="realism"):
        realism("photoreal")


@pytest.mark.slow
def test_clean_frames_are_exactly_todays():
    scene = generate_scene(0, "office", "small")
    poses = make_trajectory(scene, "loop", 2, seed=0)
    today = list(simulate_frames(scene, poses, seed=0, intrinsics=ROOM_CAMERA))
    clean = list(simulate_frames(scene, poses, seed=0, intrinsics=ROOM_CAMERA, realism="clean"))
    kinect = list(simulate_frames(scene, poses, seed=0, intrinsics=ROOM_CAMERA, realism="kinect"))
    for a, b, c in zip(today, clean, kinect, strict=True):
        assert np.array_equal(a.depth, b.depth) and np.array_equal(a.rgb, b.rgb)
        assert not np.array_equal(a.depth, c.depth)
    with pytest.raises(SimulationError, match="--no-noise"):
        list(simulate_frames(scene, poses, noise=False, realism="kinect"))


@pytest.mark.slow
def test_simulate_records_the_preset(tmp_path):
    root = simulate_sequence(tmp_path / "seq", frames=1, size="small", intrinsics=ROOM_CAMERA, realism="hard")
    assert json.loads((root / "scene.json").read_text())["realism"] == "hard"
    root = simulate_sequence(tmp_path / "seq2", frames=1, size="small", intrinsics=ROOM_CAMERA)
    assert json.loads((root / "scene.json").read_text())["realism"] == "clean"


def test_the_run_report_names_the_preset_of_simulated_frames(tmp_path):
    from semmap.datasets.simulated import SimulatedDataset
    from semmap.run.prepare import simulated_realism

    assert simulated_realism(SimulatedDataset(None, np.eye(4)[None])) == "clean"  # the demo's
    assert simulated_realism(SimulatedDataset(None, np.eye(4)[None], realism="kinect")) == "kinect"
    root = tmp_path / "seq"
    root.mkdir()
    assert simulated_realism(object(), root) is None  # recorded data
    (root / "scene.json").write_text(json.dumps({"generator_version": 1}))
    assert simulated_realism(object(), root) == "clean"  # written before presets existed
    (root / "scene.json").write_text(json.dumps({"generator_version": 1, "realism": "hard"}))
    assert simulated_realism(object(), root) == "hard"
    (root / "scene.json").write_text("{not json")
    assert simulated_realism(object(), root) is None


#: Only the systematic distortion: no noise, no quantisation to speak of, nothing dropped.
EXACT = dataclasses.replace(PLAIN, sigma_disp_px=0.0, sigma_corr_px=0.0, subpixel=1e7)


def test_zero_distortion_and_calibration_error_are_the_identity():
    assert StructuredLight().distortion_image(H, W).max() == 0.0
    assert StructuredLight().sensor_intrinsics(ROOM_CAMERA) is ROOM_CAMERA
    depth, cos = _plane(2.0)
    assert np.allclose(EXACT.apply_view(depth, cos, 0, fx=FX), depth, rtol=0, atol=1e-6)
    # the kinect preset's other parameters with the new ones at zero give the frames of before
    kinect = realism("kinect").depth_model(4)
    before = dataclasses.replace(kinect, distortion_px=0.0, distortion_field_px=0.0)
    ramp = np.linspace(1.0, 3.5, W, dtype=np.float32)[None].repeat(H, 0)
    a = before.apply_view(ramp, np.ones_like(ramp), 2, fx=FX)
    b = StructuredLight(seed=4).apply_view(ramp, np.ones_like(ramp), 2, fx=FX)
    assert np.array_equal(a, b)


def test_distortion_bias_grows_with_depth_squared_and_towards_the_corners():
    sensor = dataclasses.replace(EXACT, distortion_px=0.1)
    corner, mid, centre = (W - 1, H - 1), (W * 3 // 4, H * 3 // 4), (W // 2, H // 2)
    errs = {}
    for z in (1.0, 2.0, 3.0):
        depth, cos = _plane(z)
        out = sensor.apply_view(depth, cos, 0, fx=FX)
        for name, (u, v) in (("corner", corner), ("mid", mid), ("centre", centre)):
            errs[z, name] = float(out[v, u]) - z
            assert errs[z, name] == pytest.approx(float(sensor.depth_bias(z, u, v, H, W)), abs=1e-5)
    fb = sensor.focal_px * sensor.baseline_m
    assert errs[3.0, "corner"] == pytest.approx(fb / (fb / 3.0 + 0.1) - 3.0, rel=1e-4)  # reads ~2 cm nearer
    assert -0.025 < errs[3.0, "corner"] < -0.015
    assert abs(errs[1.0, "centre"]) < 1e-4 and abs(errs[3.0, "centre"]) < 1e-3
    for name in ("corner", "mid"):  # ~z^2: x4 and x9
        assert 3.5 < errs[2.0, name] / errs[1.0, name] < 4.5 and 8.0 < errs[3.0, name] / errs[1.0, name] < 10.0
    assert errs[3.0, "corner"] < errs[3.0, "mid"] < errs[3.0, "centre"] <= 0.0  # grows with the radius
    # Herrera's decay: the disparity bias shrinks with depth, exp(-decay (d_1m - d))
    decayed = dataclasses.replace(sensor, distortion_decay=0.05)
    ratio = decayed.disparity_bias(3.0, *corner, H, W) / sensor.disparity_bias(3.0, *corner, H, W)
    assert ratio == pytest.approx(np.exp(-0.05 * (fb - fb / 3.0)), rel=1e-6)
    assert decayed.disparity_bias(1.0, *corner, H, W) == pytest.approx(0.1, rel=1e-6)


def test_distortion_field_is_smooth_fixed_per_unit_and_seeded():
    a = dataclasses.replace(EXACT, distortion_field_px=0.05, seed=1)
    img = a.distortion_image(H, W)
    assert float(img.std()) == pytest.approx(0.05, rel=0.05)
    assert np.abs(np.diff(img, axis=1)).max() < 0.3 * 0.05  # low frequency: small steps from pixel to pixel
    assert np.array_equal(img, dataclasses.replace(a).distortion_image(H, W))  # same unit, same pattern
    assert not np.array_equal(img, dataclasses.replace(a, seed=2).distortion_image(H, W))
    depth, cos = _plane(2.5)
    f0, f7 = a.apply_view(depth, cos, 0, fx=FX), a.apply_view(depth, cos, 7, fx=FX)
    assert np.array_equal(f0, f7)  # systematic: the same in every frame (no noise in EXACT)
    with pytest.raises(SimulationError, match="distortion"):
        StructuredLight(distortion_px=float("nan"))
    with pytest.raises(SimulationError, match="focal_error"):
        StructuredLight(focal_error=0.5)


@pytest.mark.slow
def test_the_renderer_looks_through_the_true_intrinsics_and_publishes_the_nominal_ones():
    from semmap.sim.render import Renderer

    scene = generate_scene(0, "office", "small")
    poses = make_trajectory(scene, "loop", 1, seed=0)
    sensor = StructuredLight(focal_error=0.02, principal_offset_px=(4.0, -2.0))
    true = sensor.sensor_intrinsics(ROOM_CAMERA)
    assert (true.fx, true.fy, true.cx, true.cy) == pytest.approx((71.4, 71.4, 43.5, 27.5))
    r = Renderer(scene, ROOM_CAMERA, noise=sensor)
    assert r.intrinsics == ROOM_CAMERA and r.camera == true
    ids, z = r.visible(poses[0])
    ids_true, z_true = Renderer(scene, true).visible(poses[0])
    assert np.array_equal(ids, ids_true) and np.array_equal(z, z_true)
    assert not np.array_equal(z, Renderer(scene, ROOM_CAMERA).visible(poses[0])[1])
    frame = next(simulate_frames(scene, poses, seed=0, intrinsics=ROOM_CAMERA, realism="kinect"))
    assert frame.intrinsics == ROOM_CAMERA  # what a dataset publishes: the nominal calibration
    assert Renderer(scene, ROOM_CAMERA, noise=KinectNoise()).camera is ROOM_CAMERA
