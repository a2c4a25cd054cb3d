"""The room's planes in one frame's working grid: the floor (the lowest large upward-facing plane below the
camera, with nothing under it), the ceiling (the highest large downward-facing plane above it, nothing over it)
and walls (large vertical planes with nothing behind them and reaching up to eye level).

"Nothing behind it" is what tells a room's shell from furniture: a table top has floor under it, a cabinet front
has the wall behind it showing beside it, a wall has only the room in front of it."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from semmap.perception.structure.surface import Surface

FLOOR, CEILING, WALL = "floor", "ceiling", "wall"
#: A surface within this of the up direction faces up or down; within this of the horizontal it is vertical.
FACING_DEG = 25.0
#: The floor lies at least this far below the camera, the ceiling this far above it (metres).
MIN_CLEARANCE_M = 0.25
#: Heights are binned this finely (metres) to find horizontal planes, walls by direction and distance.
HEIGHT_BIN_M = 0.02
WALL_ANGLE_BIN_DEG, WALL_OFFSET_BIN_M = 5.0, 0.05
#: Smallest plane worth a label (m²) and the area at which a plane's size makes it half sure.
MIN_AREA = {FLOOR: 0.05, CEILING: 0.08, WALL: 0.15}
HALF_SURE_AREA = {FLOOR: 0.05, CEILING: 0.08, WALL: 0.15}
#: Share of what lies behind a plane (under a floor, over a ceiling, beyond a wall) at which it is no longer
#: the room's shell.
MAX_BEHIND_SHARE = {FLOOR: 0.2, CEILING: 0.2, WALL: 0.3}
#: Only what lies this close behind a plane counts against it: furniture stands a few tens of centimetres from the
#: wall behind it (a table top 0.7 m over the floor), while the next room seen through a doorway lies further.
BEHIND_REACH_M = 0.9
#: A wall shows higher than furniture fronts: sure once it reaches this far over the floor (counters are 0.9 m),
#: or, with no floor in view, this far below the camera; half as sure a ramp's width lower (a camera looking down
#: sees a wall only to its own height).
REACH_OVER_FLOOR_M, REACH_BELOW_CAMERA_M, REACH_RAMP_M = 1.0, 0.6, 0.4
#: Up to this many walls per frame.
MAX_WALLS = 8


@dataclass(frozen=True)
class Plane:
    """One plane of the room in the camera frame: points x with ``normal . x + offset = 0``; ``normal`` faces the
    camera's side (``offset`` > 0 is the camera's distance); ``sure`` in [0, 1] from its size, fit and what lies
    behind it."""

    kind: str
    normal: np.ndarray
    offset: float
    sure: float
    area: float
    behind: float

    def distance(self, points: np.ndarray) -> np.ndarray:
        """Signed distance (metres) of ``points`` (..., 3): positive on the camera's side."""
        return points @ self.normal + self.offset


def _area_sure(kind: str, area: float) -> float:
    return 1.0 - 0.5 ** (area / HALF_SURE_AREA[kind])


def _behind(surface: Surface, plane_normal: np.ndarray, offset: float, inlier_area: float) -> float:
    """Share of the area just beyond the plane (further than a tolerance, within BEHIND_REACH_M) among it and
    the plane's own area."""
    valid = surface.valid
    p = surface.points[valid]
    sd = p @ plane_normal + offset
    far = (sd < -(0.05 + 2 * surface.tolerance[valid])) & (sd > -BEHIND_REACH_M)
    behind = float(surface.area[valid][far].sum())
    return behind / max(behind + inlier_area, 1e-9)


def _fit_sure(sd: np.ndarray, tol: np.ndarray) -> float:
    """1 for inliers scattered like sensor noise about the plane, less for a rough or curved surface."""
    ratio = float(np.sqrt(np.mean(np.square(sd / tol)))) if len(sd) else 1.0
    return float(np.clip(1.5 - ratio, 0.3, 1.0))


def _peaks(values: np.ndarray, weights: np.ndarray, lo: float, hi: float, step: float) -> list[tuple[float, float]]:
    """(centre, weight) of the local maxima of a weighted histogram smoothed by [1, 2, 1]."""
    if hi <= lo or len(values) == 0:
        return []
    edges = np.arange(lo, hi + step, step)
    hist, _ = np.histogram(values, edges, weights=weights)
    smooth = np.convolve(hist, [0.25, 0.5, 0.25], mode="same")
    pad = np.pad(smooth, 1)
    peak = (smooth > pad[:-2]) & (smooth >= pad[2:]) & (smooth > 0)
    centres = (edges[:-1] + edges[1:]) / 2
    return [(float(centres[i]), float(smooth[i] * 2)) for i in np.flatnonzero(peak)]


def horizontal_plane(surface: Surface, up: np.ndarray, kind: str, *, near: float | None = None) -> Plane | None:
    """The floor (``kind`` FLOOR: lowest) or ceiling (highest) of the frame, or None; ``near`` is the height
    (relative to the camera, along ``up``) where earlier frames found it: a plane there needs less area."""
    sign = 1.0 if kind == FLOOR else -1.0
    facing = surface.normals @ (sign * up) > np.cos(np.radians(FACING_DEG))
    p = np.nan_to_num(surface.points)
    height = p @ up
    pick = facing & surface.valid & (sign * height < -MIN_CLEARANCE_M)
    if not pick.any():
        return None
    h, w = height[pick], surface.area[pick]
    peaks = _peaks(h, w, float(h.min()) - HEIGHT_BIN_M, float(h.max()) + HEIGHT_BIN_M, HEIGHT_BIN_M)
    peaks.sort(key=lambda pw: sign * pw[0])  # the floor's lowest first, the ceiling's highest first
    for centre, _ in peaks:
        tol = surface.tolerance
        band = pick & (np.abs(height - centre) < 2 * HEIGHT_BIN_M)
        level = float(np.median(height[band]))
        inl = surface.valid & facing & (np.abs(height - level) < tol)
        area = float(surface.area[inl].sum())
        known = near is not None and abs(level - near) < 0.1
        if area < (MIN_AREA[kind] / 4 if known else MIN_AREA[kind]):
            continue
        normal = sign * up
        offset = -sign * level
        behind = _behind(surface, normal, offset, area)
        if behind > MAX_BEHIND_SHARE[kind]:
            continue
        sure = (max(_area_sure(kind, area), 0.8 if known else 0.0) * _fit_sure(height[inl] - level, tol[inl])
                * (1.0 - behind / MAX_BEHIND_SHARE[kind]) ** 0.5)
        return Plane(kind, normal, offset, float(sure), area, behind)
    return None


def _fit_vertical(points: np.ndarray, weights: np.ndarray, up: np.ndarray, normal: np.ndarray,
                  offset: float) -> tuple[np.ndarray, float]:
    """The vertical plane through ``points`` by weighted least squares in the horizontal plane (the line through
    their footprint), facing like ``normal``; the input plane where the points cannot fix one."""
    if len(points) < 3:
        return normal, offset
    flat = points - np.outer(points @ up, up)
    centre = (flat * weights[:, None]).sum(axis=0) / weights.sum()
    d = flat - centre
    cov = (d * weights[:, None]).T @ d
    vals, vecs = np.linalg.eigh(cov)
    along = vecs[:, 2]  # the footprint's long direction
    if vals[2] <= 4 * max(vals[1], 1e-12):
        return normal, offset  # a blob, not a line: keep the normals' plane
    n = np.cross(up, along)
    n /= max(np.linalg.norm(n), 1e-9)
    if n @ normal < 0:
        n = -n
    return n, float(-(centre @ n))


def wall_planes(surface: Surface, up: np.ndarray, *, floor_height: float | None = None) -> list[Plane]:
    """Vertical planes large enough, with little behind them and reaching eye level: the frame's walls."""
    vertical = surface.has_normal & (np.abs(surface.normals @ up) < np.sin(np.radians(FACING_DEG)))
    p = np.nan_to_num(surface.points)
    e1 = np.cross(up, [0.0, 0.0, 1.0] if abs(up[2]) < 0.9 else [1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(up, e1)
    n = surface.normals
    horiz = n - (n @ up)[..., None] * up
    norm = np.linalg.norm(horiz, axis=-1)
    horiz = horiz / np.where(norm > 0, norm, 1.0)[..., None]
    azimuth = np.degrees(np.arctan2(horiz @ e2, horiz @ e1))
    offset = -np.sum(horiz * p, axis=-1)  # distance of the camera from the cell's vertical plane
    height = p @ up
    tol = surface.tolerance
    free = vertical & surface.valid
    walls: list[Plane] = []
    a_bins = np.arange(-180.0, 180.0 + WALL_ANGLE_BIN_DEG, WALL_ANGLE_BIN_DEG)
    for _ in range(MAX_WALLS * 2):
        if len(walls) >= MAX_WALLS or not free.any():
            break
        top = float(max(offset[free].max(), WALL_OFFSET_BIN_M))
        o_bins = np.arange(0.0, top + 2 * WALL_OFFSET_BIN_M, WALL_OFFSET_BIN_M)
        hist, _, _ = np.histogram2d(azimuth[free], offset[free], (a_bins, o_bins), weights=surface.area[free])
        hist = hist + np.roll(hist, 1, 0) + np.roll(hist, -1, 0)  # neighbours in direction (wrapping)
        hist[:, 1:] += hist[:, :-1].copy()
        i, j = np.unravel_index(int(np.argmax(hist)), hist.shape)
        if hist[i, j] < MIN_AREA[WALL]:
            break
        a0 = (a_bins[i] + a_bins[i + 1]) / 2
        o0 = o_bins[j]
        seed = free & (np.abs((azimuth - a0 + 180) % 360 - 180) < 2 * WALL_ANGLE_BIN_DEG) & \
            (np.abs(offset - o0) < 2 * WALL_OFFSET_BIN_M)
        if not seed.any():
            free[...] = False
            break
        wn = (horiz[seed] * surface.area[seed, None]).sum(axis=0)
        wn = wn - (wn @ up) * up
        wn /= max(np.linalg.norm(wn), 1e-9)
        rho = float(np.median(-(p[seed] @ wn)))
        inl = seed
        for _ in range(2):  # refit the vertical plane to its inliers' points, then take its inliers again
            wn, rho = _fit_vertical(p[inl], surface.area[inl], up, wn, rho)
            sd = p @ wn + rho
            agree = horiz @ wn > np.cos(np.radians(FACING_DEG))
            inl = surface.valid & vertical & agree & (np.abs(sd) < tol)
            if not inl.any():
                break
        free &= ~(inl | seed)
        area = float(surface.area[inl].sum())
        if area < MIN_AREA[WALL] or rho <= 0:
            continue
        behind = _behind(surface, wn, rho, area)
        if behind > MAX_BEHIND_SHARE[WALL]:
            continue
        tops = height[inl]
        reach = float(np.percentile(tops, 95))  # how high the wall shows, relative to the camera
        low = -REACH_BELOW_CAMERA_M if floor_height is None else floor_height + REACH_OVER_FLOOR_M
        reach_sure = 0.5 + 0.5 * float(np.clip((reach - low) / REACH_RAMP_M, 0.0, 1.0))
        sure = (_area_sure(WALL, area) * _fit_sure(sd[inl], tol[inl]) * (1.0 - behind / MAX_BEHIND_SHARE[WALL]) ** 0.5
                * reach_sure)
        if sure > 0.05:
            walls.append(Plane(WALL, wn, rho, float(sure), area, behind))
    return walls
