"""A depth image as a coarse grid of smoothed camera-frame points with normals and areas: what the plane search
of the structure segmenter works on (a 640x480 frame becomes 160x120 cells)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from semmap.types import CameraIntrinsics

#: Cells across the width of the working grid (a 640 px image: 4x4-pixel cells).
GRID_WIDTH = 160
#: A cell needs valid depth in at least this share of its pixels.
MIN_VALID_SHARE = 0.5
#: Neighbouring cells further apart in depth than this (metres, plus the same share of the depth) are not one
#: surface: no normal across a depth edge.
EDGE_JUMP_M, EDGE_JUMP_SHARE = 0.04, 0.04


def depth_sigma(z: np.ndarray) -> np.ndarray:
    """Axial noise (metres) of a structured-light depth camera at depth ``z`` (Nguyen et al. 2012's Kinect fit)."""
    return 0.0012 + 0.0019 * np.square(np.maximum(z - 0.4, 0.0))


def plane_tolerance(z: np.ndarray) -> np.ndarray:
    """How far (metres) a point at depth ``z`` may lie from its plane and still be on it: 1.5 cm plus three
    noise sigmas (2.9 cm at 2 m, 5.8 cm at 3.5 m)."""
    return 0.015 + 3.0 * depth_sigma(z)


@dataclass(frozen=True)
class Surface:
    """The working grid of one frame: cell centres ``points`` (h, w, 3) in the camera frame (NaN where invalid),
    unit ``normals`` (h, w, 3) facing the camera (0 where unknown), the ``area`` (h, w) in m² each cell covers,
    and the pixel size of a cell (``cell``)."""

    points: np.ndarray
    normals: np.ndarray
    area: np.ndarray
    cell: int
    depth: np.ndarray | None = None  #: each cell's depth from its camera, where the points are not camera-frame

    @property
    def tolerance(self) -> np.ndarray:
        """:func:`plane_tolerance` of each cell, from its depth."""
        z = np.nan_to_num(self.points[..., 2]) if self.depth is None else self.depth
        return plane_tolerance(z)

    @property
    def valid(self) -> np.ndarray:
        return np.isfinite(self.points[..., 2])

    @property
    def has_normal(self) -> np.ndarray:
        return np.any(self.normals != 0, axis=-1)


def cell_size(width: int) -> int:
    """Pixels per cell side for an image ``width`` pixels wide."""
    return max(1, round(width / GRID_WIDTH))


def surface_of(depth: np.ndarray, intrinsics: CameraIntrinsics, *, min_depth: float = 0.1,
               max_depth: float = 10.0) -> Surface:
    """The working grid of a depth image (float32 metres, 0 invalid): per cell the mean of its valid depths,
    smoothed over 3x3 cells, back-projected; normals from central differences of the smoothed points."""
    c = cell_size(intrinsics.width)
    h, w = depth.shape[0] // c, depth.shape[1] // c
    d = np.asarray(depth[: h * c, : w * c], np.float32)
    ok = np.isfinite(d) & (d >= min_depth) & (d <= max_depth)
    d = np.where(ok, d, 0.0).reshape(h, c, w, c)
    counts = ok.reshape(h, c, w, c).sum(axis=(1, 3))
    z = d.sum(axis=(1, 3)) / np.maximum(counts, 1)
    valid = counts >= MIN_VALID_SHARE * c * c
    z = np.where(valid, z, 0.0)
    zs = _smooth(z, valid)
    u = (np.arange(w) * c + (c - 1) / 2.0 - intrinsics.cx) / intrinsics.fx
    v = (np.arange(h) * c + (c - 1) / 2.0 - intrinsics.cy) / intrinsics.fy
    points = np.stack([zs * u[None, :], zs * v[:, None], zs], axis=-1)
    points[~valid] = np.nan
    normals = _normals(points, z, valid)
    area = np.where(valid, np.square(z * c) / (intrinsics.fx * intrinsics.fy), 0.0)
    return Surface(points, normals, area, c)


def _smooth(z: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """3x3 mean of the valid cells that lie on the same surface as the centre (within the edge jump)."""
    h, w = z.shape
    pad_z = np.pad(z, 1)
    pad_v = np.pad(valid, 1)
    total = np.zeros_like(z)
    count = np.zeros_like(z)
    limit = EDGE_JUMP_M + EDGE_JUMP_SHARE * z
    for dy in (0, 1, 2):
        for dx in (0, 1, 2):
            zz = pad_z[dy: dy + h, dx: dx + w]
            same = pad_v[dy: dy + h, dx: dx + w] & (np.abs(zz - z) < limit)
            total += np.where(same, zz, 0.0)
            count += same
    return np.where(valid, total / np.maximum(count, 1), 0.0)


def _normals(points: np.ndarray, z: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Unit normals from the cells either side along rows and columns, turned to face the camera; zero at the
    border, next to an invalid cell or across a depth edge."""
    normals = np.zeros_like(points)
    limit = 2 * (EDGE_JUMP_M + EDGE_JUMP_SHARE * z[1:-1, 1:-1])
    du = points[1:-1, 2:] - points[1:-1, :-2]
    dv = points[2:, 1:-1] - points[:-2, 1:-1]
    ok = (valid[1:-1, 2:] & valid[1:-1, :-2] & valid[2:, 1:-1] & valid[:-2, 1:-1] & valid[1:-1, 1:-1]
          & (np.abs(du[..., 2]) < limit) & (np.abs(dv[..., 2]) < limit))
    n = np.cross(du, dv)
    norm = np.linalg.norm(n, axis=-1)
    ok &= norm > 0
    n = np.where(ok[..., None], n / np.where(norm > 0, norm, 1.0)[..., None], 0.0)
    centre = np.nan_to_num(points[1:-1, 1:-1])
    flip = np.sum(n * centre, axis=-1) > 0  # facing the camera: n . p < 0
    n[flip] *= -1
    normals[1:-1, 1:-1] = n
    return normals
