"""OctoMap-exact voxel keys and ray traversal (numba), shared by every map that must agree with OctoMap.

Keys: ``key = floor(coord * (1 / resolution)) + 32768`` per axis with the coordinate a float32 promoted to
double, 16 bits per axis; packed into one int64 as ``x | y << 16 | z << 32``.  Child index at depth d
(0 = children of the root) is ``bx + 2·by + 4·bz`` of key bit ``15 - d``.

The ray traversal reproduces ``OcTreeBaseImpl::computeRayKeys`` operation for operation (float32 direction
and length, double tMax/tDelta, the float-rounded half-voxel border), so the free cells agree exactly.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from semmap.keys import KEY_LIMIT, TREE_MAX_VAL

EMPTY_KEY = np.int64(-1)


@nb.njit(cache=True, inline="always")
def pack_key(x: int, y: int, z: int) -> np.int64:
    return np.int64(x) | (np.int64(y) << 16) | (np.int64(z) << 32)


@nb.njit(cache=True, inline="always")
def key_x(k: np.int64) -> np.int64:
    return k & 0xFFFF


@nb.njit(cache=True, inline="always")
def key_y(k: np.int64) -> np.int64:
    return (k >> 16) & 0xFFFF


@nb.njit(cache=True, inline="always")
def key_z(k: np.int64) -> np.int64:
    return (k >> 32) & 0xFFFF


@nb.njit(cache=True, inline="always")
def coord_to_key(c: np.float32, res_factor: float) -> np.int64:
    """OctoMap ``coordToKey`` for one axis (may fall outside [0, KEY_LIMIT); callers check)."""
    return np.int64(math.floor(np.float64(c) * res_factor)) + TREE_MAX_VAL


@nb.njit(cache=True, inline="always")
def key_to_coord(k: np.int64, resolution: float) -> float:
    """Centre of a finest-level cell along one axis (double, as OctoMap ``keyToCoord``)."""
    return (np.float64(k - TREE_MAX_VAL) + 0.5) * resolution


@nb.njit(cache=True, inline="always")
def key_in_range(k: np.int64) -> bool:
    return 0 <= k < KEY_LIMIT


@nb.njit(cache=True, inline="always")
def _axis_setup(d: np.float32, o: np.float32, k: np.int64, resolution: float, half: float):
    """Step, first crossing and crossing interval along one axis (OctoMap's DDA initialisation)."""
    if d > 0.0:
        border = key_to_coord(k, resolution) + half
        return 1, (border - np.float64(o)) / np.float64(d), resolution / np.float64(d)
    if d < 0.0:
        border = key_to_coord(k, resolution) - half
        return -1, (border - np.float64(o)) / np.float64(d), resolution / -np.float64(d)
    return 0, 1.7976931348623157e308, 1.7976931348623157e308


@nb.njit(cache=True)
def trace_ray(ox: np.float32, oy: np.float32, oz: np.float32, ex: np.float32, ey: np.float32, ez: np.float32,
              resolution: float, res_factor: float,
              grid: np.ndarray, g0x: int, g0y: int, g0z: int, gny: int, gnz: int,
              out_keys: np.ndarray, collect: bool) -> int:
    """Free cells of the ray origin→end exactly as OctoMap's ``computeRayKeys`` (end cell excluded).

    With ``collect`` the keys go to ``out_keys`` (M, 3) and the count is returned (-1 if an end is out of
    the key range, -2 if ``out_keys`` is too small).  Otherwise each cell is marked free (1) in the dense
    ``grid`` unless already marked (hits are marked 2 before any ray runs), and the number of cells is
    returned.  The grid covers keys ``g0 + [0, n)`` per axis, z fastest.
    """
    kx = coord_to_key(ox, res_factor)
    ky = coord_to_key(oy, res_factor)
    kz = coord_to_key(oz, res_factor)
    kex = coord_to_key(ex, res_factor)
    key_ey = coord_to_key(ey, res_factor)
    kez = coord_to_key(ez, res_factor)
    if not (key_in_range(kx) and key_in_range(ky) and key_in_range(kz)
            and key_in_range(kex) and key_in_range(key_ey) and key_in_range(kez)):
        return -1
    if kx == kex and ky == key_ey and kz == kez:
        return 0
    size = grid.shape[0]
    sx = gny * gnz
    idx = (kx - g0x) * sx + (ky - g0y) * gnz + (kz - g0z)
    if collect:
        if out_keys.shape[0] < 1:
            return -2
        out_keys[0, 0] = kx
        out_keys[0, 1] = ky
        out_keys[0, 2] = kz
    elif 0 <= idx < size and grid[idx] == 0:
        grid[idx] = 1
    n = 1

    # float32 direction and length, as point3d arithmetic in OctoMap
    dx = ex - ox
    dy = ey - oy
    dz = ez - oz
    length = np.float32(math.sqrt(np.float64(dx * dx + dy * dy + dz * dz)))
    if length == 0.0:  # ends in different cells but closer than float32 can measure (denormals)
        return n
    dx = dx / length
    dy = dy / length
    dz = dz / length
    half = np.float64(np.float32(resolution * 0.5))
    stx, tmx, tdx = _axis_setup(dx, ox, kx, resolution, half)
    sty, tmy, tdy = _axis_setup(dy, oy, ky, resolution, half)
    stz, tmz, tdz = _axis_setup(dz, oz, kz, resolution, half)
    ix = stx * sx
    iy = sty * gnz
    iz = stz
    flen = np.float64(length)
    while True:
        if tmx < tmy:
            if tmx < tmz:
                kx += stx
                tmx += tdx
                idx += ix
            else:
                kz += stz
                tmz += tdz
                idx += iz
        elif tmy < tmz:
            ky += sty
            tmy += tdy
            idx += iy
        else:
            kz += stz
            tmz += tdz
            idx += iz
        if kx == kex and ky == key_ey and kz == kez:
            break
        if min(tmx, min(tmy, tmz)) > flen:
            break
        if collect:
            if n >= out_keys.shape[0]:
                return -2
            out_keys[n, 0] = kx
            out_keys[n, 1] = ky
            out_keys[n, 2] = kz
        elif 0 <= idx < size and grid[idx] == 0:
            grid[idx] = 1
        n += 1
    return n


def ray_keys(origin: np.ndarray, end: np.ndarray, resolution: float) -> np.ndarray:
    """Keys (M, 3) of the free cells OctoMap's ``computeRayKeys`` gives for one ray (float32 inputs)."""
    o = np.asarray(origin, np.float32)
    e = np.asarray(end, np.float32)
    span = np.abs(np.floor(e.astype(np.float64) / resolution) - np.floor(o.astype(np.float64) / resolution))
    out = np.empty((int(span.sum()) + 4, 3), np.int64)
    dummy = np.zeros(1, np.uint8)
    n = trace_ray(o[0], o[1], o[2], e[0], e[1], e[2], float(resolution), 1.0 / float(resolution),
                  dummy, 0, 0, 0, 1, 1, out, True)
    if n == -1:
        raise ValueError("ray end points are outside the map's key range")
    if n < 0:
        raise RuntimeError("internal error: ray key buffer too small")
    return out[:n]
