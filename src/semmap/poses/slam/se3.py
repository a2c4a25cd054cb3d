"""SE(3) helpers the SLAM modules add to :mod:`semmap.types`'s (``invert_pose``, ``transform_points``,
``rotation_angle``): the exponential retraction and OpenCV's rotation vectors."""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["exp_update", "from_rvec", "to_rvec"]


def exp_update(delta: np.ndarray) -> np.ndarray:
    """4x4 transform of a small left increment ``delta = (omega, rho)`` (rotation vector, translation)."""
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(np.asarray(delta[:3], np.float64).reshape(3, 1))[0]
    T[:3, 3] = delta[3:]
    return T


def from_rvec(rvec: np.ndarray, tvec: np.ndarray) -> np.ndarray:
    """4x4 transform from OpenCV's (rvec, tvec)."""
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(np.asarray(rvec, np.float64).reshape(3, 1))[0]
    T[:3, 3] = np.asarray(tvec, np.float64).reshape(3)
    return T


def to_rvec(T: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV's (rvec, tvec) of a 4x4 transform."""
    return cv2.Rodrigues(np.ascontiguousarray(T[:3, :3]))[0], T[:3, 3].reshape(3, 1).copy()
