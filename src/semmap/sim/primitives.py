"""Closed convex mesh primitives (box, frustum, ellipsoid) with outward winding and texture coordinates.

Every object of the simulator is a union of such parts; convexity lets the scene tests check for
interpenetration with half-space tests, and the outward winding gives the normals the renderer and the
ground-truth sampler use. UVs are metres along the face ("metric", for tiled textures) or the unit square of
the face ("fit", for posters, screens), oriented so images read upright and unmirrored from outside.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Segments around a full circle for cylinders and ellipsoids, unless a builder asks for another count.
DEFAULT_SEGMENTS = 16


@dataclass
class Part:
    """One closed convex piece: vertices (n, 3) float64 in the object frame, outward triangles, UVs, material slot."""

    vertices: np.ndarray
    triangles: np.ndarray  # (m, 3) int32
    uvs: np.ndarray  # (n, 2) float32
    material: int

    def transformed(self, R: np.ndarray, t: np.ndarray) -> Part:
        """The part moved by ``x -> R x + t``."""
        return Part(self.vertices @ np.asarray(R).T + np.asarray(t), self.triangles, self.uvs, self.material)


def rot_x(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def box(lo, hi, material: int, *, fit: bool = False, R: np.ndarray | None = None,
        pivot=None) -> Part:
    """Axis-aligned box [lo, hi] (24 vertices, 12 triangles), optionally rotated by R about ``pivot``.

    ``pivot`` defaults to the box centre.
    """
    lo = np.asarray(lo, float)
    hi = np.asarray(hi, float)
    c = (lo + hi) / 2
    h = (hi - lo) / 2
    verts, uvs, tris = [], [], []
    for k in range(3):
        a, b = np.eye(3)[(k + 1) % 3], np.eye(3)[(k + 2) % 3]
        ha, hb = h[(k + 1) % 3], h[(k + 2) % 3]
        for s in (-1.0, 1.0):
            n = np.eye(3)[k] * s
            corners = [c + n * h[k] + sa * ha * a + sb * hb * b for sa, sb in ((-1, -1), (1, -1), (1, 1), (-1, 1))]
            if s < 0:
                corners = corners[::-1]
            base = len(verts)
            verts.extend(corners)
            uvs.extend(face_uvs(np.array(corners), n, lo, fit))
            tris.extend([(base, base + 1, base + 2), (base, base + 2, base + 3)])
    part = Part(np.array(verts), np.array(tris, np.int32), np.array(uvs, np.float32), material)
    if R is not None:
        p = c if pivot is None else np.asarray(pivot, float)
        part = part.transformed(R, p - np.asarray(R) @ p)
    return part


def frustum(r_bottom: float, r_top: float, z0: float, z1: float, material: int, *, center=(0.0, 0.0),
            segments: int = DEFAULT_SEGMENTS, fit: bool = False) -> Part:
    """Truncated cone (cylinder when radii agree) along z from z0 to z1 around ``center`` (x, y), closed."""
    cx, cy = center
    ang = np.linspace(0.0, 2 * np.pi, segments + 1)
    cos, sin = np.cos(ang), np.sin(ang)
    ring_b = np.stack([cx + r_bottom * cos, cy + r_bottom * sin, np.full_like(ang, z0)], 1)
    ring_t = np.stack([cx + r_top * cos, cy + r_top * sin, np.full_like(ang, z1)], 1)
    r_mid = 0.5 * (r_bottom + r_top)
    if fit:
        u = ang / (2 * np.pi)
        uv_b = np.stack([u, np.ones_like(u)], 1)
        uv_t = np.stack([u, np.zeros_like(u)], 1)
    else:
        u = ang * r_mid
        uv_b = np.stack([u, np.full_like(u, -z0)], 1)
        uv_t = np.stack([u, np.full_like(u, -z1)], 1)
    verts = [ring_b, ring_t]
    uvs = [uv_b, uv_t]
    n1 = segments + 1
    tris = []
    for i in range(segments):
        b0, b1, t0, t1 = i, i + 1, n1 + i, n1 + i + 1
        tris += [(b0, b1, t1), (b0, t1, t0)]
    base = 2 * n1
    for z, r, top in ((z0, r_bottom, False), (z1, r_top, True)):
        if r <= 0:
            continue
        ring = np.stack([cx + r * cos[:-1], cy + r * sin[:-1], np.full(segments, z)], 1)
        verts += [np.array([[cx, cy, z]]), ring]
        uvs += [np.array([[cx, -cy]]), np.stack([ring[:, 0], -ring[:, 1]], 1)]
        for i in range(segments):
            a, b = base + 1 + i, base + 1 + (i + 1) % segments
            tris.append((base, a, b) if top else (base, b, a))
        base += 1 + segments
    tri = np.array(tris, np.int32)
    V = np.concatenate(verts)
    keep = _nondegenerate(V, tri)
    return Part(V, tri[keep], np.concatenate(uvs).astype(np.float32), material)


def ellipsoid(radii, center, material: int, *, R: np.ndarray | None = None, n_lat: int = 8,
              n_lon: int = DEFAULT_SEGMENTS) -> Part:
    """Closed ellipsoid with semi-axes ``radii`` at ``center`` (latitude-longitude mesh, pole fans)."""
    rx, ry, rz = radii
    lat = np.linspace(-np.pi / 2, np.pi / 2, n_lat + 1)[1:-1]
    lon = np.linspace(0.0, 2 * np.pi, n_lon + 1)
    la, lo = np.meshgrid(lat, lon, indexing="ij")
    ring = np.stack([rx * np.cos(la) * np.cos(lo), ry * np.cos(la) * np.sin(lo), rz * np.sin(la)], -1)
    r_xy = 0.5 * (rx + ry)
    ring_uv = np.stack([lo * r_xy, -la * rz], -1)
    V = np.concatenate([ring.reshape(-1, 3), [[0, 0, -rz], [0, 0, rz]]])
    UV = np.concatenate([ring_uv.reshape(-1, 2), [[0, np.pi / 2 * rz], [0, -np.pi / 2 * rz]]])
    n1 = n_lon + 1
    south, north = len(V) - 2, len(V) - 1
    tris = []
    for j in range(len(lat) - 1):
        for i in range(n_lon):
            a, b, c, d = j * n1 + i, j * n1 + i + 1, (j + 1) * n1 + i + 1, (j + 1) * n1 + i
            tris += [(a, b, c), (a, c, d)]
    last = (len(lat) - 1) * n1
    for i in range(n_lon):
        tris.append((south, i + 1, i))
        tris.append((north, last + i, last + i + 1))
    V = V.astype(float)
    if R is not None:
        V = V @ np.asarray(R).T
    V = V + np.asarray(center, float)
    tri = np.array(tris, np.int32)
    return Part(V, tri[_nondegenerate(V, tri)], UV.astype(np.float32), material)


def oriented_box(start, end, width: float, height: float, material: int) -> Part:
    """Box of cross-section ``width`` x ``height`` running from ``start`` to ``end`` (spokes, rods, slats)."""
    start, d, L = _segment(start, end)
    y, z = _perpendiculars(d, np.array([0.0, 0.0, 1.0]) if abs(d[2]) < 0.9 else np.array([1.0, 0.0, 0.0]))
    part = box((0.0, -width / 2, -height / 2), (L, width / 2, height / 2), material)
    return part.transformed(np.stack([d, y, z], 1), start)


def limb(start, end, r0: float, r1: float, material: int, segments: int = 10) -> Part:
    """Tapered cylinder between two points (arms, legs, poles)."""
    start, d, L = _segment(start, end)
    x, y = _perpendiculars(d, np.array([1.0, 0.0, 0.0]) if abs(d[0]) < 0.9 else np.array([0.0, 1.0, 0.0]))
    return frustum(r0, r1, 0.0, L, material, segments=segments).transformed(np.stack([x, y, d], 1), start)


def _segment(start, end) -> tuple[np.ndarray, np.ndarray, float]:
    """(start, unit direction, length) of the segment start -> end."""
    start = np.asarray(start, float)
    axis = np.asarray(end, float) - start
    L = float(np.linalg.norm(axis))
    return start, axis / L, L


def _perpendiculars(d: np.ndarray, ref: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors completing the unit direction ``d`` to a right-handed frame, the first ⟂ ``ref``."""
    a = np.cross(ref, d)
    a /= np.linalg.norm(a)
    return a, np.cross(d, a)


def face_uvs(corners: np.ndarray, n: np.ndarray, origin: np.ndarray, fit: bool) -> np.ndarray:
    """UVs of a planar face: u to the viewer's right, v downwards, seen from outside along -n."""
    if abs(n[2]) > 0.5:
        right = np.array([1.0, 0.0, 0.0])
        up = np.array([0.0, 1.0, 0.0]) * np.sign(n[2])
    else:
        right = np.cross(-n, [0.0, 0.0, 1.0])
        up = np.array([0.0, 0.0, 1.0])
    rel = corners - origin
    u = rel @ right
    v = -(rel @ up)
    if fit:
        u = (u - u.min()) / max(u.max() - u.min(), 1e-9)
        v = (v - v.min()) / max(v.max() - v.min(), 1e-9)
    return np.stack([u, v], 1)


def _nondegenerate(V: np.ndarray, tri: np.ndarray) -> np.ndarray:
    """Mask of triangles with non-zero area."""
    e1 = V[tri[:, 1]] - V[tri[:, 0]]
    e2 = V[tri[:, 2]] - V[tri[:, 0]]
    return np.linalg.norm(np.cross(e1, e2), axis=1) > 1e-12
