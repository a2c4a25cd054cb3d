"""Motion model: the camera's relative motion between updates, applied to every particle with noise that grows
with the distance travelled and the angle turned (Thrun et al., *Probabilistic Robotics* ch. 5.4).

Two state spaces (``MotionMode``): ``6dof`` moves full camera poses; ``ground`` moves (x, y, yaw) of a camera
at a known height with known roll and pitch (a robot's fixed camera mount, or gravity from an IMU), described per
update by a :class:`GroundTilt`.  Relative motions come from a :class:`MotionSource`: semmap's dense odometry,
a trajectory file, or (for experiments) the sequence's ground truth with drift added.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum
from typing import Protocol

import numpy as np

from semmap.errors import ConfigError
from semmap.types import Frame, invert_pose, make_pose, rot_z, rotation_angle


class MotionMode(str, Enum):
    """State space of the particles."""

    SIX_DOF = "6dof"  # full camera pose
    GROUND = "ground"  # x, y, yaw; height, roll and pitch known


@dataclass(frozen=True)
class MotionNoise:
    """Standard deviations of the motion noise per update: proportional parts plus a floor that keeps the
    particle set diverse while the camera stands still."""

    trans_per_m: float = 0.10  # metres of translation noise per metre travelled
    trans_per_rad: float = 0.02  # metres of translation noise per radian turned
    rot_per_rad: float = 0.10  # radians of rotation noise per radian turned
    rot_per_m: float = 0.05  # radians of rotation noise per metre travelled
    trans_floor: float = 0.01  # metres
    rot_floor_deg: float = 0.5

    def __post_init__(self) -> None:
        if min(self.trans_per_m, self.trans_per_rad, self.rot_per_rad, self.rot_per_m, self.trans_floor,
               self.rot_floor_deg) < 0:
            raise ConfigError("motion noise parameters must not be negative")

    def sigmas(self, u: np.ndarray) -> tuple[float, float]:
        """(translation σ in metres, rotation σ in radians) for the relative motion ``u`` (4, 4)."""
        d = float(np.linalg.norm(u[:3, 3]))
        a = rotation_angle(u)
        return (self.trans_per_m * d + self.trans_per_rad * a + self.trans_floor,
                self.rot_per_rad * a + self.rot_per_m * d + math.radians(self.rot_floor_deg))


def heading(R: np.ndarray) -> np.ndarray:
    """Yaw (radians) of the optical axis (third column) of rotations (..., 3, 3) about world z."""
    R = np.asarray(R)
    return np.arctan2(R[..., 1, 2], R[..., 0, 2])


@dataclass(frozen=True)
class GroundTilt:
    """What a ground-mode particle does not estimate: the camera's height (world z, metres) and its rotation
    with the heading removed (``R_world_cam = Rz(yaw) · tilt``)."""

    height: float
    tilt: np.ndarray  # (3, 3)

    @classmethod
    def from_pose(cls, T_world_cam: np.ndarray) -> GroundTilt:
        """Height and tilt of a known camera pose (the pose's own heading is dropped)."""
        R = np.asarray(T_world_cam, np.float64)[:3, :3]
        return cls(float(T_world_cam[2, 3]), rot_z(-heading(R)) @ R)

    @classmethod
    def fixed(cls, height: float, pitch_deg: float = 0.0, roll_deg: float = 0.0) -> GroundTilt:
        """A camera looking along +x, pitched by ``pitch_deg`` (negative: down) and rolled about its optical axis."""
        p, r = math.radians(pitch_deg), math.radians(roll_deg)
        f = np.array([math.cos(p), 0.0, math.sin(p)])
        x = np.cross(f, [0.0, 0.0, 1.0])
        x /= np.linalg.norm(x)
        y = np.cross(f, x)
        c, s = math.cos(r), math.sin(r)
        return cls(float(height), np.stack([c * x + s * y, -s * x + c * y, f], 1))

    def pose(self, x: float, y: float, yaw: float) -> np.ndarray:
        """Camera pose at (x, y, yaw) with this height and tilt."""
        return make_pose(rot_z(yaw) @ self.tilt, (x, y, self.height))


class MotionSource(Protocol):
    """Where the camera's motion comes from: any pose of each frame in the source's own frame (only the relative
    motion between two frames is used), or None when it has none for that frame."""

    name: str

    def pose(self, frame: Frame) -> np.ndarray | None:
        ...


class NoisyGroundTruth:
    """The frames' ground-truth poses with drift: each relative motion is perturbed by noise proportional to it
    (``trans_frac`` of the distance, ``rot_frac`` of the angle, per axis), as an odometry would (experiments)."""

    name = "gt-noisy"

    def __init__(self, trans_frac: float = 0.05, rot_frac: float = 0.05, seed: int = 0) -> None:
        if trans_frac < 0 or rot_frac < 0:
            raise ConfigError("motion noise fractions must not be negative")
        self.trans_frac, self.rot_frac = trans_frac, rot_frac
        self._rng = np.random.default_rng([seed, 0x0D0])
        self._last_gt: np.ndarray | None = None
        self._pose: np.ndarray | None = None

    def pose(self, frame: Frame) -> np.ndarray | None:
        gt = frame.T_world_cam
        if gt is None:
            return None
        if self._last_gt is None:
            self._pose = np.asarray(gt, np.float64).copy()
        else:
            u = invert_pose(self._last_gt) @ gt
            d, a = float(np.linalg.norm(u[:3, 3])), rotation_angle(u)
            noise = np.eye(4)
            w = self._rng.normal(0.0, self.rot_frac * a / math.sqrt(3), 3)
            noise[:3, :3] = _exp_so3(w)
            noise[:3, 3] = self._rng.normal(0.0, self.trans_frac * d / math.sqrt(3), 3)
            self._pose = self._pose @ u @ noise
        self._last_gt = np.asarray(gt, np.float64)
        return self._pose


class OdometrySource:
    """semmap's dense RGB-D odometry (:class:`~semmap.poses.odometry.DenseOdometry`) run on the frames as they come."""

    name = "odometry"

    def __init__(self) -> None:
        from semmap.poses.odometry import DenseOdometry

        self._tracker = DenseOdometry()

    def pose(self, frame: Frame) -> np.ndarray | None:
        return self._tracker.track(frame)


class TrajectorySource:
    """Poses of a TUM trajectory file (e.g. from ``semmap track``), looked up by frame timestamp."""

    def __init__(self, path) -> None:
        from semmap.poses.file import TrajectoryPoses

        self._poses = TrajectoryPoses.from_file(path)
        self.name = str(path)

    def pose(self, frame: Frame) -> np.ndarray | None:
        return self._poses.pose_of(frame).pose


def _exp_so3(w: np.ndarray) -> np.ndarray:
    th = float(np.linalg.norm(w))
    K = np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
    if th < 1e-12:
        return np.eye(3) + K
    return np.eye(3) + math.sin(th) / th * K + (1.0 - math.cos(th)) / th**2 * K @ K
