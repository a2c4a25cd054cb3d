"""Numba kernels of one dense-alignment Gauss-Newton step: the normal equations of the photometric + geometric
cost (or the point-to-plane one) summed over every source pixel, row by row.

The pose increment is a left one, ``T <- exp(xi) T`` with ``xi = (omega, v)``; a warped point ``p`` moves by
``omega x p + v``, so a residual with gradient ``g`` (d residual / d p) has the Jacobian ``(p x g, g)``. The target
image, depth and their gradients are read bilinearly (sub-pixel), robust weights are Huber's (iteratively
reweighted least squares). Each image row has its own partial sums, added in row order afterwards, so a step gives
the same result on every run and thread count.

A step returns a flat float64 array of ``SYSTEM_SIZE``: the 21 upper-triangle entries of ``J^T W J`` (row by row),
the 6 of ``J^T W r``, the sum of squared residuals and the number of pixels with a correspondence.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

#: Length of a step's sums: 21 (upper triangle of the 6x6 matrix) + 6 (right-hand side) + squared residuals + count.
SYSTEM_SIZE = 29


@nb.njit(cache=True, inline="always")
def _bilinear(img, u0, v0, a, b):
    return ((1.0 - a) * (1.0 - b) * img[v0, u0] + a * (1.0 - b) * img[v0, u0 + 1]
            + (1.0 - a) * b * img[v0 + 1, u0] + a * b * img[v0 + 1, u0 + 1])


@nb.njit(cache=True, inline="always")
def _warp(src_vertex, y, x, T):
    """Source pixel (y, x)'s point moved by ``T`` into the target camera; z = -1 where the source has no depth."""
    sx, sy, sz = src_vertex[y, x, 0], src_vertex[y, x, 1], src_vertex[y, x, 2]
    if not sz > 0.0:
        return 0.0, 0.0, -1.0
    return (T[0, 0] * sx + T[0, 1] * sy + T[0, 2] * sz + T[0, 3],
            T[1, 0] * sx + T[1, 1] * sy + T[1, 2] * sz + T[1, 3],
            T[2, 0] * sx + T[2, 1] * sy + T[2, 2] * sz + T[2, 3])


@nb.njit(cache=True, inline="always")
def _accumulate(row, p0, p1, p2, g0, g1, g2, r, delta):
    """Add one Huber-weighted residual ``r`` with point gradient ``g`` at warped point ``p`` to a row's sums."""
    j0 = p1 * g2 - p2 * g1
    j1 = p2 * g0 - p0 * g2
    j2 = p0 * g1 - p1 * g0
    ar = abs(r)
    w = 1.0 if ar <= delta else delta / ar
    w0, w1, w2, w3, w4, w5 = w * j0, w * j1, w * j2, w * g0, w * g1, w * g2
    row[0] += w0 * j0
    row[1] += w0 * j1
    row[2] += w0 * j2
    row[3] += w0 * g0
    row[4] += w0 * g1
    row[5] += w0 * g2
    row[6] += w1 * j1
    row[7] += w1 * j2
    row[8] += w1 * g0
    row[9] += w1 * g1
    row[10] += w1 * g2
    row[11] += w2 * j2
    row[12] += w2 * g0
    row[13] += w2 * g1
    row[14] += w2 * g2
    row[15] += w3 * g0
    row[16] += w3 * g1
    row[17] += w3 * g2
    row[18] += w4 * g1
    row[19] += w4 * g2
    row[20] += w5 * g2
    row[21] += w0 * r
    row[22] += w1 * r
    row[23] += w2 * r
    row[24] += w3 * r
    row[25] += w4 * r
    row[26] += w5 * r
    row[27] += r * r


@nb.njit(cache=True, nogil=True)
def _sum_rows(acc):
    total = np.zeros(acc.shape[1])
    for y in range(acc.shape[0]):
        for k in range(acc.shape[1]):
            total[k] += acc[y, k]
    return total


@nb.njit(parallel=True, cache=True, error_model="numpy", nogil=True)
def photometric_geometric_system(src_vertex, src_intensity, tgt_depth, tgt_intensity, tgt_depth_dx, tgt_depth_dy,
                                 tgt_intensity_dx, tgt_intensity_dy, K, T, depth_trunc, depth_huber,
                                 intensity_huber, depth_weight, intensity_weight):
    """Normal equations of ``sum huber(w_I (I_t(pi(p)) - I_s)) + huber(w_D (D_t(pi(p)) - p_z))`` over source
    pixels with a valid vertex, where ``p = T * vertex`` lands inside the target with ``|D_t - p_z| <= depth_trunc``
    (the Huber widths apply to the unweighted residuals). ``K`` is (fx, fy, cx, cy); gradients are per pixel."""
    H, W = src_intensity.shape
    fx, fy, cx, cy = K[0], K[1], K[2], K[3]
    wd, wi = depth_weight, intensity_weight
    dd, di = depth_huber * wd, intensity_huber * wi
    acc = np.zeros((H, SYSTEM_SIZE))
    for y in nb.prange(H):
        row = np.zeros(SYSTEM_SIZE)
        for x in range(W):
            px, py, pz = _warp(src_vertex, y, x, T)
            if not pz > 0.0:  # no source depth, or behind the target camera
                continue
            iz = 1.0 / pz
            u = fx * px * iz + cx
            v = fy * py * iz + cy
            if not (u >= 0.0 and v >= 0.0 and u < W - 1 and v < H - 1):
                continue
            u0, v0 = int(u), int(v)
            a, b = u - u0, v - v0
            depth = _bilinear(tgt_depth, u0, v0, a, b)
            if not abs(depth - pz) <= depth_trunc:  # NaN (a hole next to the point) fails too
                continue
            gdx = _bilinear(tgt_depth_dx, u0, v0, a, b)
            gdy = _bilinear(tgt_depth_dy, u0, v0, a, b)
            if not (math.isfinite(gdx) and math.isfinite(gdy)):
                continue
            gix = _bilinear(tgt_intensity_dx, u0, v0, a, b)
            giy = _bilinear(tgt_intensity_dy, u0, v0, a, b)
            r_i = wi * (_bilinear(tgt_intensity, u0, v0, a, b) - src_intensity[y, x])
            c0, c1 = wi * gix * fx * iz, wi * giy * fy * iz
            _accumulate(row, px, py, pz, c0, c1, -(c0 * px + c1 * py) * iz, r_i, di)
            if wd > 0.0:
                d0, d1 = wd * gdx * fx * iz, wd * gdy * fy * iz
                _accumulate(row, px, py, pz, d0, d1, -(d0 * px + d1 * py) * iz - wd, wd * (depth - pz), dd)
            row[28] += 1.0
        acc[y] = row
    return _sum_rows(acc)


@nb.njit(parallel=True, cache=True, error_model="numpy", nogil=True)
def point_to_plane_system(src_vertex, tgt_vertex, tgt_normal, K, T, distance_trunc, huber):
    """Normal equations of ``sum huber(n_t . (p - q_t))`` where ``p = T * vertex`` projects to the nearest target
    pixel, ``q_t`` and ``n_t`` are that pixel's vertex and normal, and ``|p - q_t| <= distance_trunc``."""
    H, W = src_vertex.shape[:2]
    fx, fy, cx, cy = K[0], K[1], K[2], K[3]
    acc = np.zeros((H, SYSTEM_SIZE))
    for y in nb.prange(H):
        row = np.zeros(SYSTEM_SIZE)
        for x in range(W):
            px, py, pz = _warp(src_vertex, y, x, T)
            if not pz > 0.0:  # no source depth, or behind the target camera
                continue
            u = math.floor(fx * px / pz + cx + 0.5)
            v = math.floor(fy * py / pz + cy + 0.5)
            if not (u >= 0.0 and v >= 0.0 and u < W and v < H):
                continue
            ui, vi = int(u), int(v)
            ex, ey, ez = px - tgt_vertex[vi, ui, 0], py - tgt_vertex[vi, ui, 1], pz - tgt_vertex[vi, ui, 2]
            n0, n1, n2 = tgt_normal[vi, ui, 0], tgt_normal[vi, ui, 1], tgt_normal[vi, ui, 2]
            if not (ex * ex + ey * ey + ez * ez <= distance_trunc * distance_trunc and math.isfinite(n0)):
                continue
            _accumulate(row, px, py, pz, n0, n1, n2, n0 * ex + n1 * ey + n2 * ez, huber)
            row[28] += 1.0
        acc[y] = row
    return _sum_rows(acc)


def increment(system: np.ndarray) -> np.ndarray | None:
    """The 4x4 Gauss-Newton increment ``exp(xi)`` of a step's sums (to be applied on the left), None when the system
    is singular (too few correspondences, or a geometric cost alone on one plane)."""
    if system[28] < 6:
        return None
    A = np.empty((6, 6))
    iu = np.triu_indices(6)
    A[iu] = system[:21]
    A.T[iu] = system[:21]
    try:
        xi = np.linalg.solve(A, -system[21:27])
    except np.linalg.LinAlgError:
        return None
    return _exp_se3(xi) if np.isfinite(xi).all() else None


def _exp_se3(xi: np.ndarray) -> np.ndarray:
    """SE(3) exponential of ``(omega, v)``: Rodrigues' rotation and the translation through the left Jacobian."""
    omega, v = xi[:3], xi[3:]
    theta = float(np.linalg.norm(omega))
    W = np.array([[0.0, -omega[2], omega[1]], [omega[2], 0.0, -omega[0]], [-omega[1], omega[0], 0.0]])
    W2 = W @ W
    if theta < 1e-8:
        a, b, c = 1.0, 0.5, 1.0 / 6.0
    else:
        a, b, c = math.sin(theta) / theta, (1 - math.cos(theta)) / theta**2, (theta - math.sin(theta)) / theta**3
    T = np.eye(4)
    T[:3, :3] = np.eye(3) + a * W + b * W2
    T[:3, 3] = (np.eye(3) + b * W + c * W2) @ v
    return T
