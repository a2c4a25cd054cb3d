"""Dense RGB-D alignment over cached image pyramids (the core of the dense odometry and SLAM)."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from semmap.errors import ConfigError
from semmap.poses.dense_align import METHODS, DenseAligner, DenseImage, grey
from semmap.poses.dense_kernels import photometric_geometric_system
from semmap.poses.odometry import OdometryConfig
from semmap.poses.slam import se3
from semmap.types import Frame, invert_pose, rotation_angle


@pytest.fixture(scope="module")
def desk_frames() -> list[Frame]:
    from semmap.datasets.simulated import SimulatedDataset

    ds = SimulatedDataset.default(scene_seed=0, trajectory="desk", frames=300)
    return list(itertools.islice(iter(ds), 9))


@pytest.mark.slow
@pytest.mark.parametrize("method", METHODS)
def test_every_cost_recovers_a_relative_pose_from_a_rough_guess(desk_frames, method):
    f0, f8 = desk_frames[0], desk_frames[8]
    true = invert_pose(f0.T_world_cam) @ f8.T_world_cam
    guess = se3.exp_update(np.array([0.01, -0.01, 0.005, 0.01, 0.01, -0.01])) @ true  # ~1.5 cm and ~1 degree off
    aligner = OdometryConfig(method=method).aligner(f0.intrinsics)
    out = aligner.align(aligner.image(f8.rgb, f8.depth), aligner.image(f0.rgb, f0.depth), guess)
    assert out is not None and out.fitness > 0.5 and np.isfinite(out.inlier_rmse)
    err = invert_pose(true) @ out.T
    assert np.linalg.norm(err[:3, 3]) < 2e-3
    assert np.degrees(rotation_angle(err)) < 0.1
    assert np.allclose(out.T[:3, :3] @ out.T[:3, :3].T, np.eye(3), atol=1e-9)  # a rigid transform


@pytest.mark.slow
def test_a_target_prepared_once_serves_many_sources_unchanged(desk_frames):
    aligner = OdometryConfig().aligner(desk_frames[0].intrinsics)
    target = aligner.image(desk_frames[0].rgb, desk_frames[0].depth)
    first = [aligner.align(aligner.image(f.rgb, f.depth), target, np.eye(4)).T for f in desk_frames[1:5]]
    again = [aligner.align(aligner.image(f.rgb, f.depth), aligner.image(desk_frames[0].rgb, desk_frames[0].depth),
                           np.eye(4)).T for f in desk_frames[1:5]]
    assert np.array_equal(first, again)  # sums per image row, added in row order: the same on every run


def test_the_step_gradient_is_the_derivative_of_the_cost():
    """With Huber widths too wide to bite, a step's ``J^T r`` is the derivative of half the sum of squared
    residuals under a left increment (central differences on every axis), and ``J^T J`` is symmetric positive
    definite. The target images are linear in the pixel coordinates, so their gradients are exact and the check
    tests the Jacobian itself."""
    rng = np.random.default_rng(3)
    h, w = 120, 160
    K = np.array([150.0, 150.0, 79.5, 59.5])
    u, v = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    target = DenseImage([1.5 + 0.002 * u + 0.001 * v], [0.3 + 0.002 * u - 0.001 * v], [K])
    depth = np.full((h, w), np.nan, np.float32)
    depth[30:90, 40:120] = 1.6 + 0.05 * rng.random((60, 80), dtype=np.float32)  # well inside after the motion
    source = DenseImage([depth], [rng.random((h, w), dtype=np.float32)], [K])
    T = se3.exp_update(np.array([0.01, -0.02, 0.015, 0.02, -0.01, 0.03]))

    def system(T_):
        return photometric_geometric_system(source.vertex[0], source.intensity[0], target.depth[0],
                                            target.intensity[0], *target.gradients[0], K, T_, 10.0, 1e9, 1e9,
                                            2.0, 1.0)

    at = system(T)
    step = 1e-6
    numeric = []
    for k in range(6):
        xi = np.zeros(6)
        xi[k] = step
        numeric.append((system(se3.exp_update(xi) @ T)[27] - system(se3.exp_update(-xi) @ T)[27]) / (4 * step))
    assert at[28] == 60 * 80
    assert np.allclose(at[21:27], numeric, rtol=1e-3, atol=1e-6 * np.abs(numeric).max())
    A = np.zeros((6, 6))
    A[np.triu_indices(6)] = at[:21]
    A = A + np.triu(A, 1).T
    assert np.all(np.linalg.eigvalsh(A) > 0)


def test_image_gradients_are_per_pixel_derivatives(desk_frames):
    f = desk_frames[0]
    aligner = OdometryConfig().aligner(f.intrinsics)
    ramp = np.tile(np.arange(f.intrinsics.width, dtype=np.float32) * 0.002, (f.intrinsics.height, 1))
    image = aligner.image(f.rgb, ramp + 1.0)  # depth rising 2 mm per column
    ddx, ddy = image.gradients[0][:2]
    assert np.allclose(ddx[:, 1:-1], 0.002, atol=1e-6) and np.allclose(ddy, 0.0, atol=1e-6)


def test_depth_beyond_the_limit_or_invalid_is_ignored(desk_frames):
    f = desk_frames[0]
    aligner = OdometryConfig(depth_max=1.0).aligner(f.intrinsics)
    depth = f.depth.copy()
    depth[:10] = np.nan
    image = aligner.image(f.rgb, depth)
    d = image.depth[0]
    assert np.isnan(d[:10]).all()
    assert not (d > 1.0).any()


@pytest.mark.parametrize("kwargs", [{"method": "icp"}, {"scale": 0}, {"iterations": ()}, {"iterations": (3, 0)},
                                    {"depth_max": 0.0}, {"robust_iterations": (1, 1)},
                                    {"robust_iterations": (0, -1, 2)}, {"robust_intensity_huber": 0.0}])
def test_bad_settings_are_refused_with_a_clear_error(desk_frames, kwargs):
    args = {"iterations": (10, 5, 3), "depth_max": 4.0, "loss": (0.07, 0.05, 0.1)} | kwargs
    with pytest.raises(ConfigError):
        DenseAligner(desk_frames[0].intrinsics, **args)


def _record_steps(monkeypatch) -> list[tuple[int, float]]:
    """(pyramid level, intensity Huber width) of every Gauss-Newton step the aligner takes from now on."""
    calls = []
    step = DenseAligner._step
    monkeypatch.setattr(DenseAligner, "_step", lambda self, s, t, level, T, loss: calls.append((level, loss[2]))
                        or step(self, s, t, level, T, loss))
    return calls


def test_robust_steps_follow_each_levels_plain_steps_with_the_narrow_intensity_width(desk_frames, monkeypatch):
    """Coarse to fine, each level runs its plain steps (wide intensity Huber width) and then its robust ones (narrow
    width); the config's defaults reach the aligner."""
    cfg = OdometryConfig(iterations=(2, 1, 1), robust_iterations=(0, 2, 1), robust_intensity_huber_delta=0.03)
    aligner = cfg.aligner(desk_frames[0].intrinsics)
    calls = _record_steps(monkeypatch)
    f0, f1 = desk_frames[0], desk_frames[1]
    assert aligner.align(aligner.image(f1.rgb, f1.depth), aligner.image(f0.rgb, f0.depth), np.eye(4)) is not None
    wide, narrow = cfg.intensity_huber_delta, 0.03
    assert calls == [(2, wide), (2, wide), (1, wide), (1, narrow), (1, narrow), (0, wide), (0, narrow)]
    with pytest.raises(ConfigError):
        OdometryConfig(iterations=(10, 5, 0), robust_iterations=())


def test_a_converged_plain_step_ends_its_level(desk_frames, monkeypatch):
    """An image aligned to itself from the identity converges in the first plain step of every level, and the level
    ends there, its remaining plain and robust steps skipped (they would not move the pose)."""
    cfg = OdometryConfig(iterations=(3, 3), robust_iterations=(2, 1))
    aligner = cfg.aligner(desk_frames[0].intrinsics)
    calls = _record_steps(monkeypatch)
    image = aligner.image(desk_frames[0].rgb, desk_frames[0].depth)
    out = aligner.align(image, image, np.eye(4))
    assert out is not None and np.allclose(out.T, np.eye(4), atol=1e-6)
    assert calls == [(1, cfg.intensity_huber_delta), (0, cfg.intensity_huber_delta)]


def test_a_grey_image_prepares_the_same_pyramids_as_its_colour_one(desk_frames):
    f = desk_frames[0]
    aligner = OdometryConfig().aligner(f.intrinsics)
    from_rgb, from_grey = aligner.image(f.rgb, f.depth), aligner.image(grey(f.rgb), f.depth)
    assert grey(f.rgb).dtype == np.uint8 and grey(f.rgb).shape == f.rgb.shape[:2]
    for a, b in zip(from_rgb.intensity, from_grey.intensity, strict=True):
        assert np.array_equal(a, b)
