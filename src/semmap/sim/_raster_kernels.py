"""numba z-buffer rasteriser that finds, per pixel, the same first hit a ray cast through the pixel centre does.

Coverage is tested at pixel centres with the top-left rule (watertight along shared edges: the two triangles
of an edge compute bit-identical, opposite edge equations). The depth test uses the exact ray/plane
intersection depth of each triangle, so the visible surface and its depth equal those of ray casting up to
floating-point rounding. Rows are split into bands processed in parallel; every pixel belongs to one band
and triangles are visited in index order, so the result does not depend on thread scheduling.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

#: Triangles are clipped against this camera-space depth (metres) before projection.
NEAR_CLIP = 1e-3
NO_TRIANGLE = -1


@nb.njit(cache=True)
def setup(Vw, F, R, t, fx, fy, cx, cy, width, height, sub_xy, sub_box, sub_tri, planes):  # pragma: no cover
    """Clip and project every triangle; returns the number of screen-space sub-triangles written.

    ``planes[i] = (n, h)`` is triangle i's plane ``n . X = h`` in the camera frame (X camera coordinates).
    """
    nv = Vw.shape[0]
    Vc = np.empty((nv, 3))
    for i in range(nv):
        px = Vw[i, 0] - t[0]
        py = Vw[i, 1] - t[1]
        pz = Vw[i, 2] - t[2]
        Vc[i, 0] = R[0, 0] * px + R[1, 0] * py + R[2, 0] * pz
        Vc[i, 1] = R[0, 1] * px + R[1, 1] * py + R[2, 1] * pz
        Vc[i, 2] = R[0, 2] * px + R[1, 2] * py + R[2, 2] * pz
    poly = np.empty((4, 3))
    src = np.empty((3, 3))
    n_sub = 0
    for k in range(F.shape[0]):
        for j in range(3):
            for c in range(3):
                src[j, c] = Vc[F[k, j], c]
        e1x, e1y, e1z = src[1, 0] - src[0, 0], src[1, 1] - src[0, 1], src[1, 2] - src[0, 2]
        e2x, e2y, e2z = src[2, 0] - src[0, 0], src[2, 1] - src[0, 1], src[2, 2] - src[0, 2]
        nx = e1y * e2z - e1z * e2y
        ny = e1z * e2x - e1x * e2z
        nz = e1x * e2y - e1y * e2x
        h = nx * src[0, 0] + ny * src[0, 1] + nz * src[0, 2]
        planes[k, 0] = nx
        planes[k, 1] = ny
        planes[k, 2] = nz
        planes[k, 3] = h
        if h == 0.0:  # plane through the camera centre: seen edge-on
            continue
        if src[0, 2] < NEAR_CLIP and src[1, 2] < NEAR_CLIP and src[2, 2] < NEAR_CLIP:
            continue
        # clip the polygon against z >= NEAR_CLIP (Sutherland-Hodgman with one plane)
        m = 0
        for j in range(3):
            a = src[j]
            b = src[(j + 1) % 3]
            a_in = a[2] >= NEAR_CLIP
            b_in = b[2] >= NEAR_CLIP
            if a_in:
                poly[m, 0] = a[0]
                poly[m, 1] = a[1]
                poly[m, 2] = a[2]
                m += 1
            if a_in != b_in:
                s = (NEAR_CLIP - a[2]) / (b[2] - a[2])
                poly[m, 0] = a[0] + s * (b[0] - a[0])
                poly[m, 1] = a[1] + s * (b[1] - a[1])
                poly[m, 2] = NEAR_CLIP
                m += 1
        for j in range(1, m - 1):
            u_min, u_max, v_min, v_max = 1e300, -1e300, 1e300, -1e300
            for q, idx in enumerate((0, j, j + 1)):
                x = fx * poly[idx, 0] / poly[idx, 2] + cx
                y = fy * poly[idx, 1] / poly[idx, 2] + cy
                sub_xy[n_sub, q, 0] = x
                sub_xy[n_sub, q, 1] = y
                u_min = min(u_min, x)
                u_max = max(u_max, x)
                v_min = min(v_min, y)
                v_max = max(v_max, y)
            u0 = max(0, math.ceil(u_min))
            u1 = min(width - 1, math.floor(u_max))
            v0 = max(0, math.ceil(v_min))
            v1 = min(height - 1, math.floor(v_max))
            if u0 > u1 or v0 > v1:
                continue
            sub_box[n_sub, 0] = u0
            sub_box[n_sub, 1] = u1
            sub_box[n_sub, 2] = v0
            sub_box[n_sub, 3] = v1
            sub_tri[n_sub] = k
            n_sub += 1
    return n_sub


@nb.njit(cache=True, parallel=True)
def rasterize(sub_xy, sub_box, sub_tri, n_sub, planes, fx, fy, cx, cy, band, zbuf, idbuf):  # pragma: no cover
    """Nearest triangle id and its exact depth per pixel (-1 / inf where nothing is hit)."""
    height, width = zbuf.shape
    n_bands = (height + band - 1) // band
    for b in nb.prange(n_bands):
        r0 = b * band
        r1 = min(height, r0 + band) - 1
        for v in range(r0, r1 + 1):
            for u in range(width):
                zbuf[v, u] = np.inf
                idbuf[v, u] = NO_TRIANGLE
        for s in range(n_sub):
            if sub_box[s, 3] < r0 or sub_box[s, 2] > r1:
                continue
            x0, y0 = sub_xy[s, 0, 0], sub_xy[s, 0, 1]
            x1, y1 = sub_xy[s, 1, 0], sub_xy[s, 1, 1]
            x2, y2 = sub_xy[s, 2, 0], sub_xy[s, 2, 1]
            area = (x1 - x0) * (y2 - y0) - (x2 - x0) * (y1 - y0)
            if area == 0.0:
                continue
            sgn = 1.0 if area > 0.0 else -1.0
            # edge i: A x + B y + C >= 0 inside (after orientation); coefficients negate exactly when reversed
            A0, B0, C0 = (y0 - y1) * sgn, (x1 - x0) * sgn, (x0 * y1 - x1 * y0) * sgn
            A1, B1, C1 = (y1 - y2) * sgn, (x2 - x1) * sgn, (x1 * y2 - x2 * y1) * sgn
            A2, B2, C2 = (y2 - y0) * sgn, (x0 - x2) * sgn, (x2 * y0 - x0 * y2) * sgn
            tl0 = A0 > 0.0 or (A0 == 0.0 and B0 < 0.0)
            tl1 = A1 > 0.0 or (A1 == 0.0 and B1 < 0.0)
            tl2 = A2 > 0.0 or (A2 == 0.0 and B2 < 0.0)
            k = sub_tri[s]
            pnx, pny, pnz, ph = planes[k, 0], planes[k, 1], planes[k, 2], planes[k, 3]
            va = max(r0, sub_box[s, 2])
            vb = min(r1, sub_box[s, 3])
            for v in range(va, vb + 1):
                lo = float(sub_box[s, 0])
                hi = float(sub_box[s, 1])
                ok = True
                for A, B, C, tl in ((A0, B0, C0, tl0), (A1, B1, C1, tl1), (A2, B2, C2, tl2)):
                    rest = B * v + C
                    if A > 0.0:  # u >= -rest / A
                        bound = -rest / A
                        lo = max(lo, math.ceil(bound) if tl else math.floor(bound) + 1.0)
                    elif A < 0.0:  # u <= -rest / A
                        bound = -rest / A
                        hi = min(hi, math.floor(bound) if tl else math.ceil(bound) - 1.0)
                    elif rest < 0.0 or (rest == 0.0 and not tl):
                        ok = False
                if not ok or lo > hi:
                    continue
                dy = (v - cy) / fy
                row = pny * dy + pnz
                for u in range(int(lo), int(hi) + 1):
                    den = pnx * (u - cx) / fx + row
                    if den == 0.0:
                        continue
                    z = ph / den
                    if 0.0 < z < zbuf[v, u]:
                        zbuf[v, u] = z
                        idbuf[v, u] = k
