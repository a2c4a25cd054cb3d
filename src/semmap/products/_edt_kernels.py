"""Numba kernels of the exact Euclidean distance transform (Felzenszwalb & Huttenlocher 2012, separable lower
envelopes of parabolas) and of the incremental brushfire update (site propagation, as voxblox and nvblox do)."""

from __future__ import annotations

import numba as nb
import numpy as np

INF = np.float32(1e30)


@nb.njit(cache=True, inline="always")
def _envelope_1d(f, n, d, v, z):
    """Squared distances ``d[q] = min_p (q - p)^2 + f[p]`` of one line (``v``, ``z``: scratch)."""
    k = 0
    first = -1
    for q in range(n):
        if f[q] < INF:
            first = q
            break
    if first < 0:
        for q in range(n):
            d[q] = INF
        return
    v[0] = first
    z[0] = -INF
    z[1] = INF
    for q in range(first + 1, n):
        if f[q] >= INF:
            continue
        s = ((f[q] + q * q) - (f[v[k]] + v[k] * v[k])) / (2.0 * q - 2.0 * v[k])
        while s <= z[k]:
            k -= 1
            s = ((f[q] + q * q) - (f[v[k]] + v[k] * v[k])) / (2.0 * q - 2.0 * v[k])
        k += 1
        v[k] = q
        z[k] = s
        z[k + 1] = INF
    k = 0
    for q in range(n):
        while z[k + 1] < q:
            k += 1
        d[q] = (q - v[k]) * (q - v[k]) + f[v[k]]


@nb.njit(cache=True, parallel=True)
def squared_edt(sites):
    """(nx, ny, nz) float32 squared distance (voxel units) from every voxel to the nearest True voxel of ``sites``
    (1e30 where there is none)."""
    nx, ny, nz = sites.shape
    out = np.empty((nx, ny, nz), np.float32)
    # along z (contiguous): two sweeps give the 1D distance exactly
    for i in nb.prange(nx):
        for j in range(ny):
            last = -1
            for k in range(nz):
                if sites[i, j, k]:
                    last = k
                out[i, j, k] = INF if last < 0 else np.float32((k - last) * (k - last))
            last = -1
            for k in range(nz - 1, -1, -1):
                if sites[i, j, k]:
                    last = k
                if last >= 0:
                    dd = np.float32((last - k) * (last - k))
                    if dd < out[i, j, k]:
                        out[i, j, k] = dd
    m = max(nx, ny)
    # along y, then x: lower envelopes of parabolas
    for i in nb.prange(nx):
        f = np.empty(m, np.float64)
        d = np.empty(m, np.float64)
        v = np.empty(m, np.int64)
        z = np.empty(m + 1, np.float64)
        for k in range(nz):
            top = 0.0
            for j in range(ny):
                f[j] = out[i, j, k]
                top = max(top, f[j])
            if top == 0.0:  # every voxel of the line is a site (inside an obstacle-free region): nothing moves
                continue
            _envelope_1d(f, ny, d, v, z)
            for j in range(ny):
                out[i, j, k] = d[j]
    for j in nb.prange(ny):
        f = np.empty(m, np.float64)
        d = np.empty(m, np.float64)
        v = np.empty(m, np.int64)
        z = np.empty(m + 1, np.float64)
        for k in range(nz):
            top = 0.0
            for i in range(nx):
                f[i] = out[i, j, k]
                top = max(top, f[i])
            if top == 0.0:
                continue
            _envelope_1d(f, nx, d, v, z)
            for i in range(nx):
                out[i, j, k] = d[i]
    return out


@nb.njit(cache=True, parallel=True)
def signed_distance(occupied, outside, inside, resolution):
    """(nx, ny, nz) float32 metres from the two squared transforms: ``sqrt(outside)`` in free space, ``-sqrt(inside)``
    in occupied voxels, +-inf where the other kind does not exist (one pass instead of five numpy temporaries)."""
    nx, ny, nz = occupied.shape
    out = np.empty((nx, ny, nz), np.float32)
    res = np.float32(resolution)
    far = np.float32(np.sqrt(INF) * 0.5)
    for i in nb.prange(nx):
        for j in range(ny):
            for k in range(nz):
                if occupied[i, j, k]:
                    d = np.float32(np.sqrt(inside[i, j, k]))
                    out[i, j, k] = -np.inf if d >= far else -d * res
                else:
                    d = np.float32(np.sqrt(outside[i, j, k]))
                    out[i, j, k] = np.inf if d >= far else d * res
    return out


@nb.njit(cache=True, inline="always")
def _divmod(a, d, inv_d):
    """``divmod(a, d)`` for 0 <= a by multiplying with the float reciprocal ``inv_d`` and correcting by one step
    (an integer division costs more than the rest of a wave step)."""
    q = np.int64(a * inv_d)
    r = np.int64(a) - q * d
    if r < 0:
        q -= 1
        r += d
    elif r >= d:
        q += 1
        r -= d
    return q, r


@nb.njit(cache=True, inline="always")
def _ijk(c, syz, nz, inv_syz, inv_nz):
    """Voxel coordinates of flat index ``c`` of a C-ordered (nx, ny, nz) volume (``syz`` = ny * nz)."""
    i, r = _divmod(c, syz, inv_syz)
    j, k = _divmod(r, nz, inv_nz)
    return i, j, k


@nb.njit(cache=True)
def _push(queue, head_tail, inq, c):
    if not inq[c]:
        inq[c] = True
        queue[head_tail[1] % queue.shape[0]] = c
        head_tail[1] += 1


@nb.njit(cache=True)
def brushfire_update(occupied, dist2, site, added, removed, max_d2, queue, inq, lower):
    """Update ``dist2`` (squared voxel distance to the nearest occupied voxel, flat) and ``site`` (its flat index,
    -1 = none within ``max_d2``) in place after ``added`` voxels became occupied and ``removed`` ones stopped being
    occupied (``occupied``, (nx, ny, nz) bool, already holds the new state). ``queue``/``lower`` (n, ``site``'s
    dtype) and ``inq`` (n bool, all False) are scratch, ``inq`` left all False. Returns the voxels visited."""
    nx, ny, nz = occupied.shape
    syz = ny * nz
    inv_syz, inv_nz = 1.0 / syz, 1.0 / nz
    occ = occupied.ravel()
    n = occ.shape[0]
    ht = np.zeros(2, np.int64)
    visited = 0
    # raise: every voxel whose nearest site was removed forgets it and takes the nearest live site among its
    # neighbours' (a candidate the lower wave improves), instead of re-seeding every live neighbour
    n_lower = 0
    for c in removed:
        if not occ[c]:
            dist2[c] = INF
            site[c] = -1
            _push(queue, ht, inq, c)
    while ht[0] < ht[1]:
        c = queue[ht[0] % n]
        ht[0] += 1
        inq[c] = False
        visited += 1
        ci, cj, ck = _ijk(c, syz, nz, inv_syz, inv_nz)
        best = INF
        best_site = -1
        for di in range(-1, 2):
            for dj in range(-1, 2):
                for dk in range(-1, 2):
                    a, b, e = ci + di, cj + dj, ck + dk
                    if a < 0 or b < 0 or e < 0 or a >= nx or b >= ny or e >= nz:
                        continue
                    q = (a * ny + b) * nz + e
                    s = site[q]
                    if s < 0:
                        continue
                    if not occ[s]:
                        dist2[q] = INF
                        site[q] = -1
                        _push(queue, ht, inq, q)
                    else:
                        si, sj, sk = _ijk(s, syz, nz, inv_syz, inv_nz)
                        dd = np.float32((ci - si) ** 2 + (cj - sj) ** 2 + (ck - sk) ** 2)
                        if dd < best:
                            best = dd
                            best_site = s
        if best_site >= 0 and best <= max_d2:
            dist2[c] = best
            site[c] = best_site
            lower[n_lower] = c
            n_lower += 1
    # lower: new sites and the raised voxels that found a candidate spread their site outwards
    for c in added:
        dist2[c] = 0.0
        site[c] = c
        _push(queue, ht, inq, c)
    for t in range(n_lower):
        _push(queue, ht, inq, lower[t])
    while ht[0] < ht[1]:
        c = queue[ht[0] % n]
        ht[0] += 1
        inq[c] = False
        visited += 1
        s = site[c]
        if s < 0:
            continue
        si, sj, sk = _ijk(s, syz, nz, inv_syz, inv_nz)
        ci, cj, ck = _ijk(c, syz, nz, inv_syz, inv_nz)
        for di in range(-1, 2):
            for dj in range(-1, 2):
                for dk in range(-1, 2):
                    a, b, e = ci + di, cj + dj, ck + dk
                    if a < 0 or b < 0 or e < 0 or a >= nx or b >= ny or e >= nz:
                        continue
                    dd = np.float32((a - si) ** 2 + (b - sj) ** 2 + (e - sk) ** 2)
                    if dd > max_d2:
                        continue
                    q = (a * ny + b) * nz + e
                    if dd < dist2[q]:
                        dist2[q] = dd
                        site[q] = s
                        _push(queue, ht, inq, q)
    return visited
