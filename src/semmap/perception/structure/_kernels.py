"""numba kernels of the structure segmenter: per-pixel plane probabilities at full resolution."""

from __future__ import annotations

import math

import numba as nb
import numpy as np


@nb.njit(parallel=True, cache=True, nogil=True)
def pixel_probabilities(depth: np.ndarray, rays_x: np.ndarray, rays_y: np.ndarray, normals: np.ndarray, cell: int,
                        planes: np.ndarray, kinds: np.ndarray, min_depth: float, max_depth: float,
                        cos_none: float, cos_full: float, no_normal: float, max_sure: float, max_tol: float,
                        max_excess: float, out: np.ndarray) -> None:
    """``out`` (H, W, 3): per class (``kinds`` 0 wall, 1 floor, 2 ceiling) the best of its planes (rows of
    ``planes``: nx, ny, nz, offset, sureness) at each pixel: sureness x closeness (1 within the depth's plane
    tolerance, at most ``max_tol``; a half-normal fall-off beyond, cut ``max_excess`` half-tolerances out) x normal
    agreement (of the pixel's cell in ``normals``); the three
    are scaled down together where they add up to more than 1, then by ``max_sure``."""
    h, w = depth.shape
    gh, gw = normals.shape[0], normals.shape[1]
    for v in nb.prange(h):
        gv = min(v // cell, gh - 1)
        for u in range(w):
            out[v, u, 0] = 0.0
            out[v, u, 1] = 0.0
            out[v, u, 2] = 0.0
            z = depth[v, u]
            if not (z >= min_depth and z <= max_depth):
                continue
            x = z * rays_x[u]
            y = z * rays_y[v]
            gu = min(u // cell, gw - 1)
            n0, n1, n2 = normals[gv, gu, 0], normals[gv, gu, 1], normals[gv, gu, 2]
            has_normal = n0 != 0.0 or n1 != 0.0 or n2 != 0.0
            s = 0.0012 + 0.0019 * max(z - 0.4, 0.0) ** 2
            tol = min(0.015 + 3.0 * s, max_tol)
            for i in range(planes.shape[0]):
                sd = abs(x * planes[i, 0] + y * planes[i, 1] + z * planes[i, 2] + planes[i, 3])
                excess = max(sd - tol, 0.0) / (0.5 * tol)
                if excess > max_excess:
                    continue
                near = math.exp(-0.5 * excess * excess)
                if has_normal:
                    c = n0 * planes[i, 0] + n1 * planes[i, 1] + n2 * planes[i, 2]
                    agree = min(max((c - cos_none) / (cos_full - cos_none), 0.0), 1.0)
                else:
                    agree = no_normal
                p = planes[i, 4] * near * agree
                k = kinds[i]
                if p > out[v, u, k]:
                    out[v, u, k] = p
            total = out[v, u, 0] + out[v, u, 1] + out[v, u, 2]
            scale = max_sure / total if total > 1.0 else max_sure
            out[v, u, 0] *= scale
            out[v, u, 1] *= scale
            out[v, u, 2] *= scale
