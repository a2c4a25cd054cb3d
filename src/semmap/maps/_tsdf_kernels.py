"""Numba kernels of the TSDF (:mod:`semmap.maps.tsdf`): ray integration into the sharded hash table and marching
cubes over its voxels.

The TSDF lives in a :class:`~semmap.maps._hashtable.ShardedTable`: a slot's ``logodds`` holds the voxel's truncated
signed distance (metres, positive in front of the surface) and its ``attr`` the integer weight (observations
fused, -1 = none yet). Marching cubes: the case tables are built here from the cube's geometry
(:func:`case_tables`), not copied from a published table.
"""

from __future__ import annotations

import math
from functools import cache

import numba as nb
import numpy as np

from semmap.keys import TREE_MAX_VAL
from semmap.maps._hashtable import find_or_insert, find_slot, shard_of

#: Corner ``c`` of a cube sits at offset ``(c & 1, c >> 1 & 1, c >> 2 & 1)`` voxels from its first corner.
CORNERS = np.array([(c & 1, (c >> 1) & 1, (c >> 2) & 1) for c in range(8)], np.int64)
#: The 12 edges as (first corner, second corner, axis): the second corner is the first plus one along the axis.
EDGES = np.array([(a, a | (1 << ax), ax) for ax in range(3) for a in range(8) if not a & (1 << ax)], np.int64)
#: The 6 faces as their 4 corners in cyclic order.
FACES = [(0, 1, 3, 2), (4, 5, 7, 6), (0, 1, 5, 4), (2, 3, 7, 6), (0, 2, 6, 4), (1, 3, 7, 5)]


def _edge_of(a: int, b: int) -> int:
    return next(i for i, (p, q, _) in enumerate(EDGES) if {p, q} == {a, b})


def _face_links(case: int, face: tuple[int, ...]) -> list[tuple[int, int]]:
    """Pairs of cut edges joined across one face; with four cut edges (an ambiguous face) each inside corner is cut
    off on its own, a rule that depends on the face alone, so the two cubes sharing it agree (no cracks)."""
    inside = [bool(case >> c & 1) for c in face]
    sides = [(face[i], face[(i + 1) % 4]) for i in range(4)]
    cut = [_edge_of(a, b) for i, (a, b) in enumerate(sides) if inside[i] != inside[(i + 1) % 4]]
    if len(cut) == 2:
        return [(cut[0], cut[1])]
    if len(cut) == 4:  # corners i and i+2 inside: join the two sides around each inside corner
        links = []
        for i in range(4):
            if inside[i]:
                links.append((_edge_of(*sides[(i - 1) % 4]), _edge_of(*sides[i])))
        return links
    return []


def _loops(case: int) -> list[list[int]]:
    """The closed polygons of cut edges of one case: each cut edge is linked on its two faces."""
    nbrs: dict[int, list[int]] = {}
    for face in FACES:
        for a, b in _face_links(case, face):
            nbrs.setdefault(a, []).append(b)
            nbrs.setdefault(b, []).append(a)
    loops, seen = [], set()
    for start in sorted(nbrs):
        if start in seen:
            continue
        loop, prev, cur = [start], -1, start
        seen.add(start)
        while True:
            nxt = nbrs[cur][0] if nbrs[cur][0] != prev else nbrs[cur][1]
            if nxt == start:
                break
            loop.append(nxt)
            seen.add(nxt)
            prev, cur = cur, nxt
        loops.append(loop)
    return loops


def _oriented(case: int, loop: list[int]) -> list[int]:
    """The loop turned counter-clockwise seen from outside (its normal points from inside to outside corners)."""
    mid = np.array([(CORNERS[EDGES[e][0]] + CORNERS[EDGES[e][1]]) / 2.0 for e in loop])
    normal = sum(np.cross(mid[i], mid[(i + 1) % len(mid)]) for i in range(len(mid)))
    outward = np.zeros(3)
    for e in loop:
        a, b = EDGES[e][0], EDGES[e][1]
        a_in = bool(case >> a & 1)
        outward += (CORNERS[a] - CORNERS[b]) * (-1.0 if a_in else 1.0)
    return loop if float(normal @ outward) > 0 else loop[::-1]


@cache
def case_tables() -> np.ndarray:
    """(256, 3 * T) int64 edge triples of each case's triangles (fans of its oriented loops), -1 padded; bit ``c``
    of a case is set when corner ``c`` is inside (signed distance < 0)."""
    tris = []
    for case in range(256):
        out = []
        for loop in _loops(case):
            loop = _oriented(case, loop)
            out += [(loop[0], loop[i], loop[i + 1]) for i in range(1, len(loop) - 1)]
        tris.append(out)
    width = 3 * max(len(t) for t in tris)
    table = np.full((256, width), -1, np.int64)
    for case, out in enumerate(tris):
        flat = [e for tri in out for e in tri]
        table[case, : len(flat)] = flat
    return table


# ------------------------------------------------------------------ integration
@nb.njit(cache=True, inline="always")
def _pack(x: np.int64, y: np.int64, z: np.int64) -> np.int64:
    return x | (y << 16) | (z << 32)


@nb.njit(cache=True)
def merge_points(points: np.ndarray, inv_res: float) -> tuple[np.ndarray, np.ndarray]:
    """The mean (M, 3) of the finite points (N, 3) in each voxel (in key order) and their number (M,) int32."""
    n = points.shape[0]
    packed = np.empty(n, np.int64)
    m = 0
    for i in range(n):
        x, y, z = points[i, 0], points[i, 1], points[i, 2]
        if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
            packed[i] = -1
            continue
        kx = min(max(np.int64(math.floor(x * inv_res)) + TREE_MAX_VAL, 0), 2 * TREE_MAX_VAL - 1)
        ky = min(max(np.int64(math.floor(y * inv_res)) + TREE_MAX_VAL, 0), 2 * TREE_MAX_VAL - 1)
        kz = min(max(np.int64(math.floor(z * inv_res)) + TREE_MAX_VAL, 0), 2 * TREE_MAX_VAL - 1)
        packed[i] = _pack(kx, ky, kz)
    order = np.argsort(packed, kind="mergesort")
    means = np.zeros((n, 3), np.float64)
    counts = np.zeros(n, np.int32)
    prev = np.int64(-2)
    for j in range(n):
        i = order[j]
        if packed[i] < 0:
            continue
        if packed[i] != prev:
            prev = packed[i]
            m += 1
        means[m - 1, 0] += points[i, 0]
        means[m - 1, 1] += points[i, 1]
        means[m - 1, 2] += points[i, 2]
        counts[m - 1] += 1
    for j in range(m):
        means[j] /= counts[j]
    return means[:m], counts[:m]


@nb.njit(cache=True)
def integrate_rays(keys: np.ndarray, sdf: np.ndarray, weight: np.ndarray, counts: np.ndarray, shard_cap: int,
                   fill_limit: int, points: np.ndarray, counts_per_ray: np.ndarray, origin: np.ndarray,
                   inv_res: float, trunc: float, max_weight: int, start: int, slots: np.ndarray,
                   values: np.ndarray) -> int:
    """Fuse the rays ``origin -> points[start:]`` into the table (the projective distance along each ray of every
    voxel within ``trunc`` of its end point, a running mean with integer weights up to ``max_weight``; a ray stands
    for ``counts_per_ray`` points); returns the index of the first ray not fused (``len(points)`` when all were),
    where the table must grow first."""
    res = 1.0 / inv_res
    ox, oy, oz = origin[0], origin[1], origin[2]
    for i in range(start, points.shape[0]):
        dx, dy, dz = points[i, 0] - ox, points[i, 1] - oy, points[i, 2] - oz
        dist = math.sqrt(dx * dx + dy * dy + dz * dz)
        if not dist > 1e-6 or not math.isfinite(dist):
            continue
        ux, uy, uz = dx / dist, dy / dist, dz / dist
        t0, t1 = max(dist - trunc, 0.0), dist + trunc
        # 3D DDA (Amanatides & Woo) in voxel units from t0 to t1 along the ray
        qx, qy, qz = (ox + ux * t0) * inv_res + TREE_MAX_VAL, (oy + uy * t0) * inv_res + TREE_MAX_VAL, \
            (oz + uz * t0) * inv_res + TREE_MAX_VAL
        vx, vy, vz = np.int64(math.floor(qx)), np.int64(math.floor(qy)), np.int64(math.floor(qz))
        sx, sy, sz = (1 if ux > 0 else -1), (1 if uy > 0 else -1), (1 if uz > 0 else -1)
        big = 1e30
        # metres along the ray per voxel step on each axis, and to the first boundary on each axis
        tdx, tdy, tdz = (res / abs(ux) if ux != 0 else big), (res / abs(uy) if uy != 0 else big), \
            (res / abs(uz) if uz != 0 else big)
        tmx = t0 + ((vx + (1 if sx > 0 else 0)) - qx) * res / ux if ux != 0 else big
        tmy = t0 + ((vy + (1 if sy > 0 else 0)) - qy) * res / uy if uy != 0 else big
        tmz = t0 + ((vz + (1 if sz > 0 else 0)) - qz) * res / uz if uz != 0 else big
        n = 0
        grow = False
        while n < slots.shape[0]:
            if vx < 0 or vy < 0 or vz < 0 or vx >= 2 * TREE_MAX_VAL or vy >= 2 * TREE_MAX_VAL \
                    or vz >= 2 * TREE_MAX_VAL:
                break
            cx = (vx - TREE_MAX_VAL + 0.5) * res - ox
            cy = (vy - TREE_MAX_VAL + 0.5) * res - oy
            cz = (vz - TREE_MAX_VAL + 0.5) * res - oz
            d = dist - (cx * ux + cy * uy + cz * uz)
            if d > -trunc:
                k = _pack(vx, vy, vz)
                sh = shard_of(k)
                s = find_or_insert(keys, sdf, weight, counts, sh, shard_cap, k)
                if s < 0:
                    return i  # a lane is full: grow, then this ray again (nothing of it was fused yet)
                grow = grow or counts[sh] >= fill_limit
                slots[n] = s
                values[n] = min(d, trunc)
                n += 1
            if tmx <= tmy and tmx <= tmz:
                if tmx > t1:
                    break
                vx += sx
                tmx += tdx
            elif tmy <= tmz:
                if tmy > t1:
                    break
                vy += sy
                tmy += tdy
            else:
                if tmz > t1:
                    break
                vz += sz
                tmz += tdz
        c = counts_per_ray[i]
        for j in range(n):
            s = slots[j]
            w = max(weight[s], 0)
            sdf[s] = (sdf[s] * w + values[j] * c) / (w + c)
            weight[s] = min(w + c, max_weight)
        if grow:
            return i + 1
    return points.shape[0]


# ------------------------------------------------------------------ marching cubes
@nb.njit(cache=True, parallel=True)
def cube_cases(keys: np.ndarray, sdf: np.ndarray, weight: np.ndarray, shard_cap: int, used: np.ndarray,
               min_weight: int, tables: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per used slot (the cube whose first corner it is): its case (-1 when a corner is missing or under
    ``min_weight``) and its number of triangles."""
    n = used.shape[0]
    cases = np.full(n, -1, np.int64)
    ntri = np.zeros(n, np.int64)
    for i in nb.prange(n):
        s0 = used[i]
        if weight[s0] < min_weight:
            continue
        k = keys[s0]
        case = 0
        ok = True
        for c in range(8):
            s = s0 if c == 0 else find_slot(keys, shard_cap, k + (c & 1) + (((c >> 1) & 1) << 16)
                                            + (((c >> 2) & 1) << 32))
            if s < 0 or weight[s] < min_weight:
                ok = False
                break
            if sdf[s] < 0:
                case |= 1 << c
        if ok:
            cases[i] = case
            m = 0
            while m < tables.shape[1] and tables[case, m] >= 0:
                m += 3
            ntri[i] = m // 3
    return cases, ntri


@nb.njit(cache=True, parallel=True)
def cube_triangles(keys: np.ndarray, sdf: np.ndarray, shard_cap: int, used: np.ndarray, cases: np.ndarray,
                   first: np.ndarray, tables: np.ndarray, edges: np.ndarray, res: float, edge_ids: np.ndarray,
                   positions: np.ndarray) -> None:
    """Each triangle corner's edge (first corner's packed key * 3 + axis) and the zero crossing on it (world
    metres, linear in the two corners' distances), written from ``first[i] * 3`` for cube ``i``."""
    for i in nb.prange(used.shape[0]):
        case = cases[i]
        if case <= 0 or case == 255:
            continue
        k = keys[used[i]]
        o = first[i] * 3
        m = 0
        while m < tables.shape[1] and tables[case, m] >= 0:
            e = tables[case, m]
            a, b, ax = edges[e, 0], edges[e, 1], edges[e, 2]
            ka = k + (a & 1) + (((a >> 1) & 1) << 16) + (((a >> 2) & 1) << 32)
            kb = k + (b & 1) + (((b >> 1) & 1) << 16) + (((b >> 2) & 1) << 32)
            da, db = sdf[find_slot(keys, shard_cap, ka)], sdf[find_slot(keys, shard_cap, kb)]
            t = da / (da - db) if da != db else 0.5
            edge_ids[o + m] = ka * 3 + ax
            positions[o + m, 0] = ((ka & 0xFFFF) - TREE_MAX_VAL + 0.5) * res
            positions[o + m, 1] = (((ka >> 16) & 0xFFFF) - TREE_MAX_VAL + 0.5) * res
            positions[o + m, 2] = (((ka >> 32) & 0xFFFF) - TREE_MAX_VAL + 0.5) * res
            positions[o + m, ax] += t * res
            m += 1
