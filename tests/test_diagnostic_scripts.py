"""The math behind the diagnostic scripts whose findings DESIGN.md quotes: the camera-offset fit and pose
averaging of ``scripts/tracker_agreement.py`` and the RPE of ``scripts/slam_check.py``."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from semmap.types import Trajectory

SCRIPTS = Path(__file__).resolve().parents[1] / "scripts"


def _script(name: str):
    spec = importlib.util.spec_from_file_location(f"_script_{name}", SCRIPTS / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def agreement():
    return _script("tracker_agreement")


def _walk(n: int = 120, seed: int = 0) -> Trajectory:
    """A camera wandering through a room, turning by up to about 40 degrees about every axis."""
    rng = np.random.default_rng(seed)
    t = np.linspace(0, 2 * np.pi, n)
    poses = np.tile(np.eye(4), (n, 1, 1))
    angles = np.stack([0.4 * np.sin(t + rng.uniform(0, 6)), 0.7 * np.sin(2 * t), 0.3 * np.cos(3 * t)], axis=1)
    poses[:, :3, :3] = Rotation.from_rotvec(angles).as_matrix()
    poses[:, :3, 3] = np.stack([np.cos(t), np.sin(t), 0.2 * np.sin(4 * t)], axis=1)
    return Trajectory(np.arange(n) / 30.0, poses, tuple(f"f{i}" for i in range(n)))


def _with_camera_offset(reference: Trajectory, offset: np.ndarray, seed: int = 1) -> Trajectory:
    """The reference moved rigidly into another world frame, each pose describing a point ``offset`` (camera
    frame) away from the reference's: its positions plus R_i @ offset are the reference's, moved."""
    world = np.eye(4)
    world[:3, :3] = Rotation.from_rotvec(np.random.default_rng(seed).normal(size=3)).as_matrix()
    world[:3, 3] = [0.5, -2.0, 1.0]
    shift = np.eye(4)
    shift[:3, 3] = -offset
    return Trajectory(reference.timestamps, world @ reference.poses @ shift, reference.names)


def test_camera_offset_fit_recovers_a_known_offset(agreement) -> None:
    gt = _walk()
    offset = np.array([0.03, 0.10, -0.05])
    moved = _with_camera_offset(gt, offset)
    assert agreement.ate_cm(gt, moved) > 1.0  # the offset shows as trajectory error without the fit
    [ate], fitted = agreement.ates_with_camera_offset(gt, [moved])
    assert ate < 1e-3
    np.testing.assert_allclose(fitted, 100 * offset, atol=1e-3)


def test_one_offset_for_all_cannot_fit_two_different_offsets(agreement) -> None:
    gt = _walk()
    a, b = _with_camera_offset(gt, np.array([0.0, 0.1, 0.0])), _with_camera_offset(gt, np.array([0.0, -0.1, 0.0]), 2)
    ates, fitted = agreement.ates_with_camera_offset(gt, [a, b])
    assert min(ates) > 1.0
    np.testing.assert_allclose(fitted, 0.0, atol=0.5)  # halfway between +10 and -10 cm


def test_a_true_offset_carries_over_between_halves(agreement) -> None:
    gt = _walk()
    moved = _with_camera_offset(gt, np.array([0.02, 0.08, -0.04]))
    for without, with_offset in agreement.offset_transfer(gt, moved):
        assert without > 1.0
        assert with_offset < 0.01


def test_chordal_mean_lies_between_symmetric_perturbations(agreement) -> None:
    gt = _walk(40)
    nudge = np.eye(4)
    nudge[:3, :3] = Rotation.from_rotvec([0.0, 0.05, 0.0]).as_matrix()
    nudge[:3, 3] = [0.02, 0.0, 0.0]
    ahead = Trajectory(gt.timestamps, gt.poses @ nudge, gt.names)
    behind = Trajectory(gt.timestamps, gt.poses @ np.linalg.inv(nudge), gt.names)
    mean = agreement.chordal_mean([ahead, behind])
    np.testing.assert_allclose(mean.poses[:, :3, :3], gt.poses[:, :3, :3], atol=1e-12)
    # translations average exactly; the two nudges' translations differ only by the rotation they go with
    assert np.abs(mean.poses[:, :3, 3] - gt.poses[:, :3, 3]).max() < 1e-3


def test_slam_check_rpe_reads_slightly_non_orthonormal_ground_truth_as_still() -> None:
    rpe = _script("slam_check").rpe
    gt = _walk(60).poses
    est = gt.copy()
    shrink = 1 - 3e-4 * np.random.default_rng(3).uniform(size=(len(gt), 1, 3))
    gt[:, :3, :3] *= shrink  # 7-Scenes' rotations are off orthonormal by up to this much
    trans, angle_deg = rpe(est, gt, 1)
    assert trans < 1e-3
    assert angle_deg < 0.01  # arccos of the trace reads 0.43 degrees here
    n = len(est)
    spin = Rotation.from_rotvec(np.outer(0.01 * np.arange(n), [0, 0, 1])).as_matrix()
    turned = est.copy()
    turned[:, :3, :3] = spin @ est[:, :3, :3]  # the world turning under the camera by 0.01 rad a frame
    turned[:, :3, 3] = np.einsum("nij,nj->ni", spin, est[:, :3, 3])
    _, angle_deg = rpe(turned, gt, 5)
    assert angle_deg == pytest.approx(np.degrees(0.05), rel=1e-3)
