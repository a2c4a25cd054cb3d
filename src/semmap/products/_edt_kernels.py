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


# --- incremental update (site propagation). ``site`` holds each voxel's nearest occupied voxel as packed coordinates
# ``i << 2b | j << b | k`` (b = ``bits``; -1 = none within reach), so a wave step reads a site's coordinates with
# shifts instead of divisions. The volume may be split at an x plane between two threads: each runs the waves of
# its own half, and the voxels a wave reaches across the plane are handed to their owner between rounds. A thread
# writes only its own voxels; a read across the plane may see a value its owner is changing, which costs at most a
# candidate the next round corrects (in the raise wave sites only die, in the lower wave distances only fall).
# One thread owning the whole volume (split = nx) is the sequential update.


@nb.njit(cache=True, inline="always")
def _unpack(p, bits, mask):
    """Coordinates of a packed site."""
    return p >> (2 * bits), (p >> bits) & mask, p & mask


@nb.njit(cache=True, inline="always")
def _owns(t, a, split):
    """Whether thread ``t`` owns x slice ``a``."""
    return a < split if t == 0 else a >= split


@nb.njit(cache=True)
def _ring_push(queue, ring, inq, c, t, base, cap):
    """Queue voxel ``c`` on thread ``t``'s ring (``ring[8t:8t+3]`` = head, tail, size) unless it is queued."""
    if not inq[c]:
        inq[c] = True
        tail = ring[8 * t + 1]
        queue[base[t] + tail] = c
        ring[8 * t + 1] = 0 if tail + 1 == cap[t] else tail + 1
        ring[8 * t + 2] += 1


@nb.njit(cache=True, inline="always")
def _note_across(t, p, pend_flag, pend_list, pend_n):
    """Note plane cell ``p`` for the other thread; True when it was not noted yet."""
    if pend_flag[t, p]:
        return False
    pend_flag[t, p] = True
    pend_list[t, pend_n[t]] = p
    pend_n[t] += 1
    return True


@nb.njit(cache=True)
def _raise_part(t, split, occ, shape, bits, dist2, site, max_d2, queue, ring, inq, lower, n_lower, base, cap,
                pend_flag, pend_list, pend_n):
    """Thread ``t``'s raise wave until its ring is empty: voxels whose site died forget it and take the nearest live
    site among their neighbours' as a candidate (listed in ``lower``). Returns the voxels visited."""
    nx, ny, nz = shape[0], shape[1], shape[2]
    syz, mask = ny * nz, (1 << bits) - 1
    inv_syz, inv_nz = 1.0 / syz, 1.0 / nz
    lo, hi = base[t], base[t] + cap[t]
    head, tail, size = ring[8 * t], ring[8 * t + 1], ring[8 * t + 2]
    visited = 0
    while size > 0:
        c = queue[lo + head]
        head = 0 if lo + head + 1 == hi else head + 1
        size -= 1
        inq[c] = False
        visited += 1
        ci, cj, ck = _ijk(c, syz, nz, inv_syz, inv_nz)
        best = INF
        best_site = -1
        for di in range(-1, 2):
            a = ci + di
            if a < 0 or a >= nx:
                continue
            own = _owns(t, a, split)
            for dj in range(-1, 2):
                b = cj + dj
                if b < 0 or b >= ny:
                    continue
                row = (a * ny + b) * nz
                for dk in range(-1, 2):
                    e = ck + dk
                    if e < 0 or e >= nz:
                        continue
                    q = row + e
                    s = site[q]
                    if s < 0:
                        continue
                    si, sj, sk = _unpack(s, bits, mask)
                    if occ[(si * ny + sj) * nz + sk]:
                        dd = np.float32((ci - si) ** 2 + (cj - sj) ** 2 + (ck - sk) ** 2)
                        if dd < best:
                            best = dd
                            best_site = s
                    elif not own:
                        _note_across(t, b * nz + e, pend_flag, pend_list, pend_n)
                    else:
                        dist2[q] = INF
                        site[q] = -1
                        if not inq[q]:
                            inq[q] = True
                            queue[lo + tail] = q
                            tail = 0 if lo + tail + 1 == hi else tail + 1
                            size += 1
        if best_site >= 0 and best <= max_d2:
            dist2[c] = best
            site[c] = best_site
            lower[lo + n_lower[t]] = c
            n_lower[t] += 1
    ring[8 * t], ring[8 * t + 1], ring[8 * t + 2] = head, tail, size
    return visited


@nb.njit(cache=True)
def _lower_part(t, split, shape, bits, dist2, site, max_d2, queue, ring, inq, base, cap, pend_flag, pend_list,
                pend_n, pend_d2, pend_site):
    """Thread ``t``'s lower wave until its ring is empty: each queued voxel offers its site to its 26 neighbours.
    Returns the voxels visited."""
    nx, ny, nz = shape[0], shape[1], shape[2]
    syz, mask = ny * nz, (1 << bits) - 1
    inv_syz, inv_nz = 1.0 / syz, 1.0 / nz
    lo, hi = base[t], base[t] + cap[t]
    head, tail, size = ring[8 * t], ring[8 * t + 1], ring[8 * t + 2]
    visited = 0
    while size > 0:
        c = queue[lo + head]
        head = 0 if lo + head + 1 == hi else head + 1
        size -= 1
        inq[c] = False
        visited += 1
        s = site[c]
        if s < 0:
            continue
        si, sj, sk = _unpack(s, bits, mask)
        ci, cj, ck = _ijk(c, syz, nz, inv_syz, inv_nz)
        for di in range(-1, 2):
            a = ci + di
            if a < 0 or a >= nx:
                continue
            own = _owns(t, a, split)
            ddi = (a - si) * (a - si)
            for dj in range(-1, 2):
                b = cj + dj
                if b < 0 or b >= ny:
                    continue
                ddij = ddi + (b - sj) * (b - sj)
                row = (a * ny + b) * nz
                for dk in range(-1, 2):
                    e = ck + dk
                    if e < 0 or e >= nz:
                        continue
                    dd = np.float32(ddij + (e - sk) * (e - sk))
                    q = row + e
                    if dd > max_d2 or dd >= dist2[q]:
                        continue
                    if own:
                        dist2[q] = dd
                        site[q] = s
                        if not inq[q]:
                            inq[q] = True
                            queue[lo + tail] = q
                            tail = 0 if lo + tail + 1 == hi else tail + 1
                            size += 1
                    else:
                        p = b * nz + e
                        if _note_across(t, p, pend_flag, pend_list, pend_n) or dd < pend_d2[t, p]:
                            pend_d2[t, p] = dd
                            pend_site[t, p] = s
    ring[8 * t], ring[8 * t + 1], ring[8 * t + 2] = head, tail, size
    return visited


@nb.njit(cache=True)
def _hand_over(lowering, split, occ, shape, bits, dist2, site, queue, ring, inq, base, cap, pend_flag, pend_list,
               pend_n, pend_d2, pend_site):
    """Between rounds: the plane cells each thread noted go to their owner's ring (a dead site is forgotten, a
    better site taken). Returns how many were queued."""
    ny, nz = shape[1], shape[2]
    mask = (1 << bits) - 1
    queued = 0
    for t in range(2):
        plane = split if t == 0 else split - 1
        for m in range(pend_n[t]):
            p = pend_list[t, m]
            pend_flag[t, p] = False
            q = plane * ny * nz + p
            if lowering:
                if pend_d2[t, p] >= dist2[q]:
                    continue
                dist2[q] = pend_d2[t, p]
                site[q] = pend_site[t, p]
            else:
                s = site[q]
                if s < 0:
                    continue
                si, sj, sk = _unpack(s, bits, mask)
                if occ[(si * ny + sj) * nz + sk]:
                    continue
                dist2[q] = INF
                site[q] = -1
            _ring_push(queue, ring, inq, q, 1 - t, base, cap)
            queued += 1
        pend_n[t] = 0
    return queued


@nb.njit(cache=True)
def _seed(occ, shape, bits, dist2, site, added, removed, queue, ring, inq, base, cap, raising):
    """Queue the removed voxels (raising) or the added ones (lowering, as their own sites) on their owner's ring."""
    ny, nz = shape[1], shape[2]
    syz = ny * nz
    inv_syz, inv_nz = 1.0 / syz, 1.0 / nz
    for c in removed if raising else added:
        if raising and occ[c]:
            continue
        if raising:
            dist2[c] = INF
            site[c] = -1
        else:
            i, j, k = _ijk(c, syz, nz, inv_syz, inv_nz)
            dist2[c] = 0.0
            site[c] = (i << (2 * bits)) | (j << bits) | k
        _ring_push(queue, ring, inq, c, 0 if c < base[1] else 1, base, cap)


def _waves(occupied, dist2, site, added, removed, max_d2, queue, inq, lower, bits, split, pend_flag, pend_list,
           pend_d2, pend_site, threads):
    """Raise, then lower, on ``threads`` (1 or 2) parts split at x = ``split``, in rounds until no wave crosses."""
    nx, ny, nz = occupied.shape
    shape = np.array([nx, ny, nz], np.int64)
    occ = occupied.ravel()
    base = np.array([0, split * ny * nz], np.int64)
    cap = np.array([split * ny * nz, max((nx - split) * ny * nz, 1)], np.int64)
    ring = np.zeros(16, np.int64)
    n_lower = np.zeros(2, np.int64)
    pend_n = np.zeros(2, np.int64)
    visits = np.zeros(2, np.int64)
    _seed(occ, shape, bits, dist2, site, added, removed, queue, ring, inq, base, cap, True)
    while True:
        for t in nb.prange(threads):
            visits[t] += _raise_part(t, split, occ, shape, bits, dist2, site, max_d2, queue, ring, inq, lower,
                                     n_lower, base, cap, pend_flag, pend_list, pend_n)
        if _hand_over(False, split, occ, shape, bits, dist2, site, queue, ring, inq, base, cap, pend_flag,
                      pend_list, pend_n, pend_d2, pend_site) == 0:
            break
    _seed(occ, shape, bits, dist2, site, added, removed, queue, ring, inq, base, cap, False)
    for t in range(2):
        for m in range(n_lower[t]):
            _ring_push(queue, ring, inq, lower[base[t] + m], t, base, cap)
    while True:
        for t in nb.prange(threads):
            visits[t] += _lower_part(t, split, shape, bits, dist2, site, max_d2, queue, ring, inq, base, cap,
                                     pend_flag, pend_list, pend_n, pend_d2, pend_site)
        if _hand_over(True, split, occ, shape, bits, dist2, site, queue, ring, inq, base, cap, pend_flag,
                      pend_list, pend_n, pend_d2, pend_site) == 0:
            break
    return visits[0] + visits[1]


_waves_serial = nb.njit(cache=True)(_waves)  # prange is range here: no thread pool woken for one part
_waves_parallel = nb.njit(cache=True, parallel=True)(_waves)


def brushfire_update(occupied, dist2, site, added, removed, max_d2, queue, inq, lower, bits, pending, split=None):
    """Update ``dist2`` (squared voxel distance to the nearest occupied voxel, flat) and ``site`` (packed
    coordinates of that voxel, -1 = none within ``max_d2``) in place after ``added`` voxels became occupied and
    ``removed`` ones stopped being occupied (``occupied``, (nx, ny, nz) bool, already holds the new state).
    ``queue``/``lower`` (n, ``site``'s dtype), ``inq`` (n bool, all False) and ``pending`` (the four (2, ny * nz)
    plane arrays, the flags all False) are scratch and left as found. ``split`` (0 < split < nx) runs the update
    on two threads, the volume divided at that x plane. Returns the voxels visited."""
    nx = occupied.shape[0]
    threads = 2 if split is not None and 0 < split < nx else 1
    waves = _waves_parallel if threads == 2 else _waves_serial
    return waves(occupied, dist2, site, added, removed, max_d2, queue, inq, lower, bits,
                 split if threads == 2 else nx, *pending, threads)
