"""Back-projection of depth images (paper eq. 7) and voxel filtering, vectorised over whole images."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numba as nb
import numpy as np

from semmap.errors import ConfigError
from semmap.types import CameraIntrinsics, ColorCamera, Frame

#: Default valid depth range of a Kinect-class sensor (metres).
DEFAULT_MIN_DEPTH = 0.1
DEFAULT_MAX_DEPTH = 8.0


@dataclass(frozen=True)
class PixelRays:
    """Per-pixel unit-depth ray directions of a camera, cached per intrinsics: x = (u - cx)/fx, y = (v - cy)/fy."""

    x: np.ndarray  # (W,) float64
    y: np.ndarray  # (H,) float64


_RAY_CACHE: dict[CameraIntrinsics, PixelRays] = {}


def pixel_rays(intrinsics: CameraIntrinsics) -> PixelRays:
    rays = _RAY_CACHE.get(intrinsics)
    if rays is None:
        u = np.arange(intrinsics.width, dtype=np.float64)
        v = np.arange(intrinsics.height, dtype=np.float64)
        rays = PixelRays((u - intrinsics.cx) / intrinsics.fx, (v - intrinsics.cy) / intrinsics.fy)
        _RAY_CACHE[intrinsics] = rays
    return rays


def _check_backprojection(depth: np.ndarray, intrinsics: CameraIntrinsics, min_depth: float, max_depth: float,
                          stride: int) -> None:
    if depth.shape != (intrinsics.height, intrinsics.width):
        raise ConfigError(f"depth image {depth.shape} does not match the camera "
                          f"({intrinsics.height}, {intrinsics.width})")
    if not 0 <= min_depth < max_depth:
        raise ConfigError(f"depth range must satisfy 0 <= min < max, got [{min_depth}, {max_depth}]")
    if stride < 1:
        raise ConfigError(f"pixel stride must be >= 1, got {stride}")


def backproject(depth: np.ndarray, intrinsics: CameraIntrinsics, *, min_depth: float = DEFAULT_MIN_DEPTH,
                max_depth: float = DEFAULT_MAX_DEPTH, stride: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Camera-frame points of the valid depth pixels (eq. 7: X = Z(u-cx)/fx, Y = Z(v-cy)/fy, Z = d).

    Returns ``points_cam`` (N, 3) float64 and ``pixel_index`` (N,) int64 (flat index v*W + u into the image),
    keeping pixels with ``min_depth <= d <= max_depth``; ``stride`` > 1 subsamples rows and columns.
    """
    _check_backprojection(depth, intrinsics, min_depth, max_depth, stride)
    rays = pixel_rays(intrinsics)
    d = depth[::stride, ::stride]
    valid = (d >= min_depth) & (d <= max_depth) & np.isfinite(d)
    vs, us = np.nonzero(valid)
    z = d[vs, us].astype(np.float64)
    vs *= stride
    us *= stride
    points = np.empty((z.shape[0], 3), np.float64)
    points[:, 0] = rays.x[us] * z
    points[:, 1] = rays.y[vs] * z
    points[:, 2] = z
    return points, vs.astype(np.int64) * intrinsics.width + us


@nb.njit(cache=True, parallel=True, nogil=True)
def _backproject_world(depth, rx, ry, T, min_depth, max_depth, stride):
    H, W = depth.shape
    rows = (H + stride - 1) // stride
    counts = np.zeros(rows + 1, np.int64)
    for r in nb.prange(rows):
        v = r * stride
        c = 0
        for u in range(0, W, stride):
            d = depth[v, u]
            if d >= min_depth and d <= max_depth:
                c += 1
        counts[r + 1] = c
    for r in range(rows):
        counts[r + 1] += counts[r]
    n = counts[rows]
    pts = np.empty((n, 3), np.float32)
    pix = np.empty(n, np.int64)
    for r in nb.prange(rows):
        v = r * stride
        i = counts[r]
        for u in range(0, W, stride):
            d = depth[v, u]
            if d >= min_depth and d <= max_depth:
                z = np.float64(d)
                x = rx[u] * z
                y = ry[v] * z
                pts[i, 0] = T[0, 0] * x + T[0, 1] * y + T[0, 2] * z + T[0, 3]
                pts[i, 1] = T[1, 0] * x + T[1, 1] * y + T[1, 2] * z + T[1, 3]
                pts[i, 2] = T[2, 0] * x + T[2, 1] * y + T[2, 2] * z + T[2, 3]
                pix[i] = v * W + u
                i += 1
    return pts, pix


def backproject_world(depth: np.ndarray, intrinsics: CameraIntrinsics, T_world_cam: np.ndarray, *,
                      min_depth: float = DEFAULT_MIN_DEPTH, max_depth: float = DEFAULT_MAX_DEPTH,
                      stride: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """World-frame points (N, 3) float32 of the valid depth pixels (eq. 7, then ``T_world_cam``), computed
    in double and rounded once, plus their flat pixel indices; one parallel pass, no temporaries."""
    _check_backprojection(depth, intrinsics, min_depth, max_depth, stride)
    rays = pixel_rays(intrinsics)
    return _backproject_world(np.ascontiguousarray(depth, np.float32), rays.x, rays.y,
                              np.ascontiguousarray(T_world_cam, np.float64), float(min_depth), float(max_depth),
                              int(stride))


def voxel_filter(points: np.ndarray, resolution: float) -> np.ndarray:
    """Indices of one point per occupied voxel (the first one in input order), as the paper's voxel filter.

    Voxels follow OctoMap's grid: cell = floor(coord / resolution) per axis.
    """
    if resolution <= 0:
        raise ConfigError(f"voxel size must be positive, got {resolution}")
    if len(points) == 0:
        return np.zeros(0, np.int64)
    cells = np.floor(np.asarray(points, np.float64) / resolution).astype(np.int64)
    cells -= cells.min(axis=0)
    dims = cells.max(axis=0) + 1
    flat = (cells[:, 0] * dims[1] + cells[:, 1]) * dims[2] + cells[:, 2]
    _, first = np.unique(flat, return_index=True)
    return np.sort(first)


def color_maps(depth: np.ndarray, depth_camera: CameraIntrinsics,
               color_camera: ColorCamera) -> tuple[np.ndarray, np.ndarray]:
    """For every depth pixel, where it lies in the colour image: (map_x, map_y) float32, as ``cv2.remap`` takes.

    Each depth pixel is back-projected at its depth, moved into the colour camera and projected there. Pixels
    without depth use the frame's median depth (their colour is then only approximately placed; they carry no
    3D point anyway).
    """
    rays = pixel_rays(depth_camera)
    valid = depth > 0
    z = np.where(valid, depth, np.float32(np.median(depth[valid]) if valid.any() else 2.0)).astype(np.float32)
    tx, ty, tz = (np.float32(v) for v in color_camera.t_color_depth)
    zc = z + tz
    zc[zc <= 1e-3] = 1e-3
    inv = np.float32(1.0) / zc
    c = color_camera
    map_x = (rays.x.astype(np.float32)[None, :] * z + tx) * inv * np.float32(c.fx) + np.float32(c.cx)
    map_y = (rays.y.astype(np.float32)[:, None] * z + ty) * inv * np.float32(c.fy) + np.float32(c.cy)
    return map_x, map_y


def register_color(rgb: np.ndarray, depth: np.ndarray, depth_camera: CameraIntrinsics,
                   color_camera: ColorCamera) -> np.ndarray:
    """Colour resampled (bilinearly) onto the depth camera's pixel grid, so ``rgb[v, u]`` shows what
    ``depth[v, u]`` measured (see :func:`color_maps`)."""
    map_x, map_y = color_maps(depth, depth_camera, color_camera)
    return cv2.remap(np.ascontiguousarray(rgb), map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def onto_depth_grid(frame: Frame, *per_color_pixel: np.ndarray) -> tuple[np.ndarray, ...]:
    """Per-pixel arrays of the frame's raw colour image (``frame.raw_color``: class ids, probabilities) carried
    onto its depth grid by nearest-pixel sampling (the sampling maps are computed once for all of them); returned
    as they are for frames whose colour needs no registration."""
    if frame.raw_color is None:
        return per_color_pixel
    map_x, map_y = color_maps(frame.depth, frame.intrinsics, frame.raw_color.camera)

    def remap(arr: np.ndarray) -> np.ndarray:
        out = cv2.remap(np.ascontiguousarray(arr), map_x, map_y, cv2.INTER_NEAREST, borderMode=cv2.BORDER_REPLICATE)
        return out.reshape(*frame.depth.shape, *arr.shape[2:])

    out = []
    for arr in per_color_pixel:
        if arr.ndim == 3 and arr.shape[2] > 4:  # cv2.remap takes at most 4 channels at a time
            out.append(np.dstack([remap(arr[..., i:i + 4]) for i in range(0, arr.shape[2], 4)]))
        else:
            out.append(remap(arr))
    return tuple(out)


@nb.njit(cache=True, parallel=True, nogil=True)
def _pixel_normals(depth, rx, ry, R, pixels, max_jump):
    H, W = depth.shape
    out = np.zeros((pixels.shape[0], 3), np.float32)
    for i in nb.prange(pixels.shape[0]):
        v = pixels[i] // W
        u = pixels[i] - v * W
        z = np.float64(depth[v, u])
        # neighbours left/right and up/down with valid, continuous depth (one-sided where needed)
        ul, ur = max(u - 1, 0), min(u + 1, W - 1)
        vu, vd = max(v - 1, 0), min(v + 1, H - 1)
        if depth[v, ul] <= 0 or abs(depth[v, ul] - z) > max_jump * z:
            ul = u
        if depth[v, ur] <= 0 or abs(depth[v, ur] - z) > max_jump * z:
            ur = u
        if depth[vu, u] <= 0 or abs(depth[vu, u] - z) > max_jump * z:
            vu = v
        if depth[vd, u] <= 0 or abs(depth[vd, u] - z) > max_jump * z:
            vd = v
        if ul == ur or vu == vd:
            continue
        zl, zr, zu, zd = np.float64(depth[v, ul]), np.float64(depth[v, ur]), np.float64(depth[vu, u]), np.float64(
            depth[vd, u])
        ax = rx[ur] * zr - rx[ul] * zl
        ay = ry[v] * (zr - zl)
        az = zr - zl
        bx = rx[u] * (zd - zu)
        by = ry[vd] * zd - ry[vu] * zu
        bz = zd - zu
        nx = ay * bz - az * by
        ny = az * bx - ax * bz
        nz = ax * by - ay * bx
        norm = np.sqrt(nx * nx + ny * ny + nz * nz)
        if norm == 0.0:
            continue
        # face the camera: the normal points against the viewing ray (x, y, 1) * z
        if nx * rx[u] + ny * ry[v] + nz > 0.0:
            norm = -norm
        nx, ny, nz = nx / norm, ny / norm, nz / norm
        out[i, 0] = R[0, 0] * nx + R[0, 1] * ny + R[0, 2] * nz
        out[i, 1] = R[1, 0] * nx + R[1, 1] * ny + R[1, 2] * nz
        out[i, 2] = R[2, 0] * nx + R[2, 1] * ny + R[2, 2] * nz
    return out


#: Neighbouring depths further apart than this fraction of the depth are a different surface (no normal across).
NORMAL_MAX_DEPTH_JUMP = 0.05


def pixel_normals(depth: np.ndarray, intrinsics: CameraIntrinsics, T_world_cam: np.ndarray,
                  pixels: np.ndarray) -> np.ndarray:
    """World-frame unit normals (N, 3) float32 at flat pixel indices ``pixels`` of a depth image: the cross
    product of the back-projected central differences along u and v, facing the camera; zero where a pixel has
    no valid neighbour on a side (depth edges, holes)."""
    if depth.shape != (intrinsics.height, intrinsics.width):
        raise ConfigError(f"depth image {depth.shape} does not match the camera "
                          f"({intrinsics.height}, {intrinsics.width})")
    rays = pixel_rays(intrinsics)
    return _pixel_normals(np.ascontiguousarray(depth, np.float32), rays.x, rays.y,
                          np.ascontiguousarray(np.asarray(T_world_cam, np.float64)[:3, :3]),
                          np.ascontiguousarray(pixels, np.int64), NORMAL_MAX_DEPTH_JUMP)
