"""Constant-velocity Kalman filter on image boxes (DeepSORT's), vectorised over tracks.

State ``(x, y, a, h, vx, vy, va, vh)``: box centre, aspect ratio w / h, height and their velocities (pixels and
pixels per frame); the measurement is ``(x, y, a, h)``. Process and measurement noise scale with the box height,
so a near, large box may move more pixels than a far, small one. Prediction is the paper's eqs. 1-2, the update
eqs. 3-7.
"""

from __future__ import annotations

import numpy as np

#: 0.95 quantile of the chi-square distribution with 4 degrees of freedom: Mahalanobis gate of a measurement.
CHI2_GATE_4DOF = 9.4877
#: DeepSORT's noise weights: position noise = STD_POSITION x height, velocity noise = STD_VELOCITY x height.
STD_POSITION = 1.0 / 20.0
STD_VELOCITY = 1.0 / 160.0

_A = np.eye(8)
_A[:4, 4:] = np.eye(4)  # x_k = x_{k-1} + v_{k-1} (one frame)
_H = np.eye(4, 8)


def boxes_to_measurements(boxes: np.ndarray) -> np.ndarray:
    """(N, 4) boxes ``x0, y0, x1, y1`` (inclusive pixels) -> (N, 4) ``x, y, a, h`` (centre, w / h, height)."""
    b = np.asarray(boxes, np.float64).reshape(-1, 4)
    w = b[:, 2] - b[:, 0] + 1.0
    h = b[:, 3] - b[:, 1] + 1.0
    return np.column_stack([b[:, 0] + 0.5 * (w - 1.0), b[:, 1] + 0.5 * (h - 1.0), w / h, h])


def measurements_to_boxes(z: np.ndarray) -> np.ndarray:
    """Inverse of :func:`boxes_to_measurements`."""
    z = np.asarray(z, np.float64).reshape(-1, 4)
    h = z[:, 3]
    w = z[:, 2] * h
    x0 = z[:, 0] - 0.5 * (w - 1.0)
    y0 = z[:, 1] - 0.5 * (h - 1.0)
    return np.column_stack([x0, y0, x0 + w - 1.0, y0 + h - 1.0])


def initiate(z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean (N, 8) and covariance (N, 8, 8) of new tracks from measurements (N, 4): zero velocity, wide."""
    z = np.asarray(z, np.float64).reshape(-1, 4)
    mean = np.concatenate([z, np.zeros_like(z)], axis=1)
    h = z[:, 3]
    std = np.column_stack([2 * STD_POSITION * h, 2 * STD_POSITION * h, np.full_like(h, 1e-2),
                           2 * STD_POSITION * h, 10 * STD_VELOCITY * h, 10 * STD_VELOCITY * h,
                           np.full_like(h, 1e-5), 10 * STD_VELOCITY * h])
    cov = np.zeros((len(z), 8, 8))
    idx = np.arange(8)
    cov[:, idx, idx] = std**2
    return mean, cov


def predict(mean: np.ndarray, cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """One frame ahead: eq. 1 ``x = A x`` and eq. 2 ``P = A P A^T + Q``."""
    h = mean[:, 3]
    std = np.column_stack([STD_POSITION * h, STD_POSITION * h, np.full_like(h, 1e-2), STD_POSITION * h,
                           STD_VELOCITY * h, STD_VELOCITY * h, np.full_like(h, 1e-5), STD_VELOCITY * h])
    idx = np.arange(8)
    Q = np.zeros_like(cov)
    Q[:, idx, idx] = std**2
    return mean @ _A.T, _A @ cov @ _A.T + Q


def project(mean: np.ndarray, cov: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Predicted measurement ``H x`` (T, 4) and its covariance eq. 4 ``S = H P H^T + R`` (T, 4, 4)."""
    h = mean[:, 3]
    std = np.column_stack([STD_POSITION * h, STD_POSITION * h, np.full_like(h, 1e-1), STD_POSITION * h])
    idx = np.arange(4)
    R = np.zeros((len(mean), 4, 4))
    R[:, idx, idx] = std**2
    return mean @ _H.T, _H @ cov @ _H.T + R


def update(mean: np.ndarray, cov: np.ndarray, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Correct tracks (T, 8) / (T, 8, 8) with their measurements (T, 4): eqs. 3-7."""
    z_pred, S = project(mean, cov)
    y = z - z_pred  # eq. 3, the innovation
    PHt = cov @ _H.T
    K = np.linalg.solve(S, PHt.transpose(0, 2, 1)).transpose(0, 2, 1)  # eq. 5, K = P H^T S^-1 (S symmetric)
    new_mean = mean + np.einsum("tij,tj->ti", K, y)  # eq. 6
    new_cov = (np.eye(8) - K @ _H) @ cov  # eq. 7
    return new_mean, 0.5 * (new_cov + new_cov.transpose(0, 2, 1))


def gating_distance(mean: np.ndarray, cov: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Squared Mahalanobis distances (T, N) of measurements (N, 4) from each track's predicted measurement."""
    if len(mean) == 0 or len(z) == 0:
        return np.zeros((len(mean), len(z)))
    z_pred, S = project(mean, cov)
    L = np.linalg.cholesky(S)  # (T, 4, 4)
    d = (np.asarray(z, np.float64)[None, :, :] - z_pred[:, None, :]).transpose(0, 2, 1)  # (T, 4, N)
    sol = np.linalg.solve(L, d)  # L^-1 d, per track
    return (sol**2).sum(axis=1)
