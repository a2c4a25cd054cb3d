"""numba kernels of the particle filter: motion composition and the per-particle scores, parallel over particles.

They take only contiguous arrays and scalars; :mod:`semmap.localization.filter` and
:mod:`semmap.localization.observation` validate and unpack first.  Grids are the flat arrays of
:class:`~semmap.localization.prior.PriorMap` (cell ``(ix, iy, iz)`` at ``(ix * ny + iy) * nz + iz``).
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np


@nb.njit(cache=True, parallel=True)
def propagate_6dof(R, t, uR, ut, noise):
    """In place ``T_i <- T_i · u · Exp(noise_i)``: each particle (R (N, 3, 3), t (N, 3)) moved by the relative
    camera motion u = (uR, ut) and then by its own perturbation ``noise`` (N, 6) = (translation, rotation
    vector) in the moved camera's frame (Rodrigues' formula for Exp)."""
    n = R.shape[0]
    for i in nb.prange(n):
        wx, wy, wz = noise[i, 3], noise[i, 4], noise[i, 5]
        th2 = wx * wx + wy * wy + wz * wz
        if th2 < 1e-16:
            a, b = 1.0, 0.5
        else:
            th = math.sqrt(th2)
            a = math.sin(th) / th
            b = (1.0 - math.cos(th)) / th2
        e00, e01, e02 = 1.0 - b * (wy * wy + wz * wz), -a * wz + b * wx * wy, a * wy + b * wx * wz
        e10, e11, e12 = a * wz + b * wx * wy, 1.0 - b * (wx * wx + wz * wz), -a * wx + b * wy * wz
        e20, e21, e22 = -a * wy + b * wx * wz, a * wx + b * wy * wz, 1.0 - b * (wx * wx + wy * wy)
        for r in range(3):
            q0, q1, q2 = R[i, r, 0], R[i, r, 1], R[i, r, 2]
            m0 = q0 * uR[0, 0] + q1 * uR[1, 0] + q2 * uR[2, 0]  # row r of R · uR
            m1 = q0 * uR[0, 1] + q1 * uR[1, 1] + q2 * uR[2, 1]
            m2 = q0 * uR[0, 2] + q1 * uR[1, 2] + q2 * uR[2, 2]
            t[i, r] += q0 * ut[0] + q1 * ut[1] + q2 * ut[2] + m0 * noise[i, 0] + m1 * noise[i, 1] + m2 * noise[i, 2]
            R[i, r, 0] = m0 * e00 + m1 * e10 + m2 * e20
            R[i, r, 1] = m0 * e01 + m1 * e11 + m2 * e21
            R[i, r, 2] = m0 * e02 + m1 * e12 + m2 * e22


@nb.njit(cache=True, parallel=True, fastmath=True)
def score_likelihood(R, t, pts, labels, probs, others_share, origin, res, nx, ny, nz, nearest_packed, class_q,
                     n_cls, use_semantics, eps, lut_geo, lut_gauss, lut_log, d2_scale, x_scale, log_rand, out):
    """Sum over the scan's points of log p(point | particle) for each particle (Thrun's likelihood field with a
    class term): ``log(z_hit · exp(-d²/2σ²) · f + z_rand)`` with d the distance from the point, placed by the
    particle, to the nearest occupied voxel's centre, and f = ``(1 - eps) · C' · Σ_c q(c) P_map(c) + eps`` the
    agreement of the point's class distribution q with the voxel's P_map (C' = n_cls - 1 real classes, so that an
    uninformative class gives f = 1); f = 1 for points without classes (``others_share < 0``) or with
    ``use_semantics`` off.  Points off the grid or farther than the cutoff score ``log_rand`` = log(z_rand).

    The mixture is read from small tables (no exp/log per point, all in the L1/L2 cache):
    ``lut_geo[round(d² · d2_scale)]`` for f = 1, else ``lut_log[round(x · x_scale)]`` with x =
    ``lut_gauss[round(d² · d2_scale)] · f``; the last distance entry stands for every larger distance.
    The cell record (:func:`~semmap.localization.prior.pack_nearest`) gives the voxel and its cell offset, so
    the distance needs no second memory access; the class row is read only for points near a surface.
    R (N, 3, 3), t (N, 3) float64 camera poses; pts (P, 3) float32 camera-frame points; labels/probs (P, k) their
    top-k sets (classes outside 1..C-1 given as 0 with probability 0); others_share (P,) the "others" mass per
    class outside the set; class_q (M, >= C) uint8 voxel class probabilities x 255, class 0 zero; result in
    out (N,)."""
    n = R.shape[0]
    n_pts = pts.shape[0]
    k = labels.shape[1]
    real = n_cls - 1
    last_d = lut_geo.shape[0] - 1
    last_x = lut_log.shape[0] - 1
    q_scale = 1.0 / 255.0
    inv_res = 1.0 / res
    d2_cells = d2_scale * res * res
    ox, oy, oz = origin[0], origin[1], origin[2]
    for i in nb.prange(n):
        r00, r01, r02 = R[i, 0, 0], R[i, 0, 1], R[i, 0, 2]
        r10, r11, r12 = R[i, 1, 0], R[i, 1, 1], R[i, 1, 2]
        r20, r21, r22 = R[i, 2, 0], R[i, 2, 1], R[i, 2, 2]
        t0, t1, t2 = t[i, 0], t[i, 1], t[i, 2]
        acc = 0.0
        for j in range(n_pts):
            px, py, pz = pts[j, 0], pts[j, 1], pts[j, 2]
            fx = (r00 * px + r01 * py + r02 * pz + t0 - ox) * inv_res
            fy = (r10 * px + r11 * py + r12 * pz + t1 - oy) * inv_res
            fz = (r20 * px + r21 * py + r22 * pz + t2 - oz) * inv_res
            if fx < 0.0 or fy < 0.0 or fz < 0.0 or fx >= nx or fy >= ny or fz >= nz:
                acc += log_rand
                continue
            ix, iy, iz = int(fx), int(fy), int(fz)
            rec = nearest_packed[(ix * ny + iy) * nz + iz]
            if rec < 0:
                acc += log_rand
                continue
            # distance to the nearest voxel's centre, in cells: that voxel lies at the cell offset in the record
            dx = fx - (ix + ((rec >> 32) & 0xFF) - 128) - 0.5
            dy = fy - (iy + ((rec >> 40) & 0xFF) - 128) - 0.5
            dz = fz - (iz + ((rec >> 48) & 0xFF) - 128) - 0.5
            qd = min(int((dx * dx + dy * dy + dz * dz) * d2_cells + 0.5), last_d)
            if qd == last_d:
                acc += log_rand
                continue
            share = others_share[j]
            if not use_semantics or share < 0.0:
                acc += lut_geo[qd]
                continue
            v = rec & 0xFFFFFFFF
            s = 0.0
            in_set = 0.0
            for c in range(k):
                q = float(class_q[v, labels[j, c]])
                s += probs[j, c] * q
                in_set += q
            s = (s + share * max(255.0 - in_set, 0.0)) * q_scale
            f = (1.0 - eps) * real * s + eps
            acc += lut_log[min(int(lut_gauss[qd] * f * x_scale + 0.5), last_x)]
        out[i] = acc


@nb.njit(cache=True, parallel=True, fastmath=True)
def score_cosine(R, t, pts, local_labels, origin, inv_res, nx, ny, nz, top_label, out):
    """The paper's weight (Sec. IV-C): cosine similarity of the local map's class labels (P,) with the prior map's
    labels at the same voxels, for each particle placing the local voxels (P, 3, camera frame) in the world.
    Labels are compared as the numbers they are, as described; cells the map lacks read 0."""
    n = R.shape[0]
    n_pts = pts.shape[0]
    norm_a = 0.0
    for j in range(n_pts):
        norm_a += float(local_labels[j]) * float(local_labels[j])
    norm_a = math.sqrt(norm_a)
    ox, oy, oz = origin[0], origin[1], origin[2]
    for i in nb.prange(n):
        r00, r01, r02 = R[i, 0, 0], R[i, 0, 1], R[i, 0, 2]
        r10, r11, r12 = R[i, 1, 0], R[i, 1, 1], R[i, 1, 2]
        r20, r21, r22 = R[i, 2, 0], R[i, 2, 1], R[i, 2, 2]
        t0, t1, t2 = t[i, 0], t[i, 1], t[i, 2]
        dot = 0.0
        norm_b = 0.0
        for j in range(n_pts):
            px, py, pz = pts[j, 0], pts[j, 1], pts[j, 2]
            fx = (r00 * px + r01 * py + r02 * pz + t0 - ox) * inv_res
            fy = (r10 * px + r11 * py + r12 * pz + t1 - oy) * inv_res
            fz = (r20 * px + r21 * py + r22 * pz + t2 - oz) * inv_res
            if fx < 0.0 or fy < 0.0 or fz < 0.0 or fx >= nx or fy >= ny or fz >= nz:
                continue
            b = float(top_label[(int(fx) * ny + int(fy)) * nz + int(fz)])
            dot += float(local_labels[j]) * b
            norm_b += b * b
        out[i] = dot / (norm_a * math.sqrt(norm_b)) if norm_b > 0.0 and norm_a > 0.0 else 0.0


@nb.njit(cache=True)
def inlier_fraction(R, t, pts, origin, inv_res, nx, ny, nz, nearest, centers, max_d2):
    """Share of the scan's points (P, 3, camera frame) that, placed by the pose (R, t), lie within sqrt(max_d2)
    of an occupied voxel centre: how well one pose explains the scan."""
    n_pts = pts.shape[0]
    if n_pts == 0:
        return 0.0
    hits = 0
    for j in range(n_pts):
        x = R[0, 0] * pts[j, 0] + R[0, 1] * pts[j, 1] + R[0, 2] * pts[j, 2] + t[0]
        y = R[1, 0] * pts[j, 0] + R[1, 1] * pts[j, 1] + R[1, 2] * pts[j, 2] + t[1]
        z = R[2, 0] * pts[j, 0] + R[2, 1] * pts[j, 1] + R[2, 2] * pts[j, 2] + t[2]
        fx = (x - origin[0]) * inv_res
        fy = (y - origin[1]) * inv_res
        fz = (z - origin[2]) * inv_res
        if fx < 0.0 or fy < 0.0 or fz < 0.0 or fx >= nx or fy >= ny or fz >= nz:
            continue
        v = nearest[(int(fx) * ny + int(fy)) * nz + int(fz)]
        if v < 0:
            continue
        dx, dy, dz = x - centers[v, 0], y - centers[v, 1], z - centers[v, 2]
        if dx * dx + dy * dy + dz * dz <= max_d2:
            hits += 1
    return hits / n_pts


def compile_kernels() -> None:
    """Run every kernel once on tiny inputs so numba compiles (or loads from its cache) them before the first
    update is timed."""
    R = np.tile(np.eye(3), (2, 1, 1))
    t = np.zeros((2, 3))
    pts = np.ones((3, 3), np.float32)
    labels = np.ones((3, 2), np.uint16)
    probs = np.full((3, 2), 0.4, np.float32)
    others = np.full(3, 0.2, np.float32)
    origin = np.zeros(3)
    packed = np.full(8, -1, np.int64)
    nearest = np.full(8, -1, np.int32)
    out = np.zeros(2)
    propagate_6dof(R, t, np.eye(3), np.zeros(3), np.zeros((2, 6)))
    score_likelihood(R, t, pts, labels, probs, others, origin, 0.5, 2, 2, 2, packed, np.zeros((1, 32), np.uint8),
                     3, True, 0.2, np.zeros(4), np.zeros(4), np.zeros(4), 1.0, 1.0, -3.0, out)
    score_cosine(R, t, pts, labels[:, 0].copy(), origin, 2.0, 2, 2, 2, np.zeros(8, np.uint16), out)
    inlier_fraction(R[0], t[0], pts, origin, 2.0, 2, 2, 2, nearest, np.zeros((1, 3), np.float32), 0.01)
