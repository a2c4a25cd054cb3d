"""Camera pose from 3D-2D matches: PnP with RANSAC (OpenCV), then a robust pose-only Gauss-Newton refinement
that also uses the measured depth as a virtual stereo coordinate (vectorised numpy)."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from semmap.poses.slam import se3
from semmap.types import snap_rigid, transform_points

#: chi-square 95% thresholds for 2 (pixel) and 3 (pixel + virtual stereo) degrees of freedom
CHI2_MONO = 5.991
CHI2_STEREO = 7.815


@dataclass(frozen=True)
class PinholeModel:
    """Intrinsics plus the virtual stereo baseline term ``bf = fx * b`` (pixels * metres)."""

    fx: float
    fy: float
    cx: float
    cy: float
    bf: float

    @property
    def K(self) -> np.ndarray:
        return np.array([[self.fx, 0, self.cx], [0, self.fy, self.cy], [0, 0, 1.0]])

    def project(self, pc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixel coordinates (N, 2) and virtual right u (N,) of camera-frame points (z must be positive)."""
        z = pc[:, 2]
        u = self.fx * pc[:, 0] / z + self.cx
        v = self.fy * pc[:, 1] / z + self.cy
        return np.stack([u, v], 1), u - self.bf / z


def pnp_ransac(pts_w: np.ndarray, uv: np.ndarray, cam: PinholeModel, T_cw_guess: np.ndarray | None,
               reproj_error: float, iterations: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray] | None:
    """``(T_cam_world, inlier mask)`` from PnP + RANSAC on 3D world points and pixels, or None on failure."""
    if len(pts_w) < 6:
        return None
    cv2.setRNGSeed(seed)
    guess = T_cw_guess is not None
    rvec, tvec = se3.to_rvec(T_cw_guess) if guess else (np.zeros((3, 1)), np.zeros((3, 1)))
    try:
        ok, rvec, tvec, inl = cv2.solvePnPRansac(
            np.ascontiguousarray(pts_w, np.float64), np.ascontiguousarray(uv, np.float64), cam.K, None,
            rvec, tvec, useExtrinsicGuess=guess, iterationsCount=int(iterations),
            reprojectionError=float(reproj_error), confidence=0.999, flags=cv2.SOLVEPNP_EPNP)
    except cv2.error:
        return None
    if not ok or inl is None or len(inl) < 6:
        return None
    mask = np.zeros(len(pts_w), bool)
    mask[inl.ravel()] = True
    T = se3.from_rvec(rvec, tvec)
    if not np.isfinite(T).all():
        return None
    return T, mask


def refine_pose(T_cw: np.ndarray, pts_w: np.ndarray, uv: np.ndarray, ur: np.ndarray, inv_sigma2: np.ndarray,
                cam: PinholeModel, disp_sigma: float = 1.0, rounds: int = 4,
                iterations: int = 6) -> tuple[np.ndarray, np.ndarray]:
    """Pose-only robust least squares on reprojection errors plus, where ``ur`` is finite, the error of the
    virtual stereo disparity ``u - ur = bf / z`` (standard deviation ``disp_sigma`` pixels, set by the depth noise).

    Runs ``rounds`` of Gauss-Newton with a Huber kernel, re-classifying outliers by chi-square after each
    round (outliers sit out the next round); returns the refined ``T_cam_world`` and the inlier mask.
    """
    n = len(pts_w)
    stereo = np.isfinite(ur)
    disp = np.where(stereo, uv[:, 0] - np.where(stereo, ur, 0.0), 0.0)  # measured bf / z
    wd = np.full(n, 1.0 / disp_sigma**2)  # disparity weight, independent of the pyramid level
    inlier = np.ones(n, bool)
    T = T_cw.copy()
    huber_m, huber_s = np.sqrt(CHI2_MONO), np.sqrt(CHI2_STEREO)
    thr = np.where(stereo, CHI2_STEREO, CHI2_MONO)
    hub = np.where(stereo, huber_s, huber_m)
    for rnd in range(rounds):
        for _ in range(iterations):
            pc = transform_points(T, pts_w)
            z = pc[:, 2]
            ok = inlier & (z > 1e-3)
            if ok.sum() < 6:
                return T, np.zeros(n, bool)
            p, zz = pc[ok], z[ok]
            x, y = p[:, 0], p[:, 1]
            iz, iz2 = 1.0 / zz, 1.0 / (zz * zz)
            pred_u = cam.fx * x * iz + cam.cx
            pred_v = cam.fy * y * iz + cam.cy
            st = stereo[ok].astype(np.float64)
            e = np.stack([uv[ok, 0] - pred_u, uv[ok, 1] - pred_v, (disp[ok] - cam.bf * iz) * st], 1)
            # Jacobian of (u, v, ur) w.r.t. a left increment (omega, rho): d(proj)/d(point) @ [-[p]x | I]
            a, b = cam.fx * iz, -cam.fx * x * iz2
            c, d = cam.fy * iz, -cam.fy * y * iz2
            dr = -cam.bf * iz2 * st  # d(bf / z)/dz
            zp, yp, xp = p[:, 2], p[:, 1], p[:, 0]
            zero = np.zeros_like(a)
            J = np.empty((len(p), 3, 6))
            J[:, 0] = np.stack([b * yp, a * zp - b * xp, -a * yp, a, zero, b], 1)
            J[:, 1] = np.stack([-c * zp + d * yp, -d * xp, c * xp, zero, c, d], 1)
            J[:, 2] = np.stack([dr * yp, -dr * xp, zero, zero, zero, dr], 1)
            w3 = np.column_stack([inv_sigma2[ok], inv_sigma2[ok], wd[ok] * st])
            chi = np.sqrt(np.maximum((e * e * w3).sum(1), 1e-12))
            hk = hub[ok]
            w3 = w3 * np.where(chi <= hk, 1.0, hk / chi)[:, None]
            Jf = J.reshape(-1, 6)
            Jw = Jf * w3.reshape(-1)[:, None]
            H = Jw.T @ Jf
            g = Jw.T @ e.reshape(-1)
            try:
                delta = np.linalg.solve(H + 1e-9 * np.eye(6), g)
            except np.linalg.LinAlgError:
                return T, np.zeros(n, bool)
            T = se3.exp_update(delta) @ T
            if np.abs(delta).max() < 1e-7:
                break
        # re-classify every observation (outliers may come back)
        pc = transform_points(T, pts_w)
        front = pc[:, 2] > 1e-3
        zsafe = np.where(front, pc[:, 2], 1.0)
        puv, _ = cam.project(np.column_stack([pc[:, :2], zsafe]))
        chi2 = ((uv - puv) ** 2).sum(1) * inv_sigma2 + np.where(stereo, (disp - cam.bf / zsafe) ** 2 * wd, 0.0)
        inlier = front & (chi2 < thr)
        if rnd == rounds - 2:
            hub = np.full(n, np.inf)  # last round without the robust kernel, on inliers only
    return snap_rigid(T), inlier
