"""Small SE(3) helpers (inverse, exponential retraction, batched transforms) used by every SLAM module."""

from __future__ import annotations

import cv2
import numpy as np

from semmap.types import rotation_angle

__all__ = ["exp_update", "from_rvec", "inverse", "rotation_angle", "to_rvec", "transform"]


def inverse(T: np.ndarray) -> np.ndarray:
    """Inverse of a rigid 4x4 transform (or a stack of them)."""
    out = np.zeros_like(T)
    Rt = np.swapaxes(T[..., :3, :3], -1, -2)
    out[..., :3, :3] = Rt
    out[..., :3, 3] = -(Rt @ T[..., :3, 3:4])[..., 0]
    out[..., 3, 3] = 1.0
    return out


def exp_update(delta: np.ndarray) -> np.ndarray:
    """4x4 transform of a small left increment ``delta = (omega, rho)`` (rotation vector, translation)."""
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(np.asarray(delta[:3], np.float64).reshape(3, 1))[0]
    T[:3, 3] = delta[3:]
    return T


def transform(T: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Apply one 4x4 transform to (N, 3) points."""
    return p @ T[:3, :3].T + T[:3, 3]


def from_rvec(rvec: np.ndarray, tvec: np.ndarray) -> np.ndarray:
    """4x4 transform from OpenCV's (rvec, tvec)."""
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(np.asarray(rvec, np.float64).reshape(3, 1))[0]
    T[:3, 3] = np.asarray(tvec, np.float64).reshape(3)
    return T


def to_rvec(T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV's (rvec, tvec) of a 4x4 transform."""
    return cv2.Rodrigues(np.ascontiguousarray(T[:3, :3]))[0], T[:3, 3].reshape(3, 1).copy()
