"""Dense RGB-D alignment (photometric + geometric Gauss-Newton, Open3D's tensor odometry steps) over image
pyramids that are built once per frame.

Open3D's one-call ``rgbd_odometry_multi_scale`` rebuilds both images' pyramids and the target's gradients on every
call; a tracker aligns many frames to one keyframe, so here each frame is prepared once (:meth:`DenseAligner.image`)
and a target keeps its gradients. At 640x480 that saves about a third of the dense odometry's time per frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import open3d as o3d

from semmap.errors import ConfigError
from semmap.types import CameraIntrinsics, snap_rigid

_ODOMETRY = o3d.t.pipelines.odometry
#: Cost functions: photometric + geometric, photometric only, geometric only.
METHODS = ("hybrid", "intensity", "point_to_plane")


@dataclass(frozen=True)
class AlignResult:
    """A dense alignment: ``T_target_source``, the fraction of pixels with a correspondence, and their RMSE."""

    T: np.ndarray
    fitness: float
    inlier_rmse: float


def _tensor(a: np.ndarray) -> o3d.core.Tensor:
    return o3d.core.Tensor(np.ascontiguousarray(a, np.float32))


class DenseImage:
    """One frame prepared for dense alignment: depth (NaN invalid), intensity and vertex-map pyramids (finest
    level first), plus what a target needs (image gradients, normals), computed on first use as a target and kept."""

    def __init__(self, depth: list[np.ndarray], intensity: list[np.ndarray], K: list[o3d.core.Tensor]) -> None:
        self.depth = [_tensor(d[..., None]) for d in depth]
        self.intensity = [_tensor(i[..., None]) for i in intensity]
        self.vertex = [o3d.t.geometry.Image(d).create_vertex_map(k, float("nan")).as_tensor()
                       for d, k in zip(self.depth, K, strict=True)]
        self._gradients: list[tuple[o3d.core.Tensor, ...]] | None = None
        self._normals: list[o3d.core.Tensor] | None = None

    @property
    def gradients(self) -> list[tuple[o3d.core.Tensor, ...]]:
        """Per level: (depth dx, depth dy, intensity dx, intensity dy) Sobel gradients."""
        if self._gradients is None:
            self._gradients = []
            for d, i in zip(self.depth, self.intensity, strict=True):
                ddx, ddy = o3d.t.geometry.Image(d).filter_sobel(3)
                idx, idy = o3d.t.geometry.Image(i).filter_sobel(3)
                self._gradients.append((ddx.as_tensor(), ddy.as_tensor(), idx.as_tensor(), idy.as_tensor()))
        return self._gradients

    @property
    def normals(self) -> list[o3d.core.Tensor]:
        """Per level: the normal map of the vertex map (point-to-plane targets only)."""
        if self._normals is None:
            self._normals = [_tensor(_normal_map(v.numpy())) for v in self.vertex]
        return self._normals


def _normal_map(vertex: np.ndarray) -> np.ndarray:
    """Unit normals (facing the camera) of an (H, W, 3) vertex map from central differences; NaN at the border,
    where a neighbour is invalid, and where the surface is seen edge-on."""
    normals = np.full_like(vertex, np.nan)
    dx = vertex[1:-1, 2:] - vertex[1:-1, :-2]
    dy = vertex[2:, 1:-1] - vertex[:-2, 1:-1]
    n = np.cross(dx, dy)
    with np.errstate(invalid="ignore", divide="ignore"):
        n /= np.linalg.norm(n, axis=2, keepdims=True)
        n *= -np.sign(np.sum(n * vertex[1:-1, 1:-1], axis=2, keepdims=True))  # towards the camera
    normals[1:-1, 1:-1] = n
    return normals


def grey(colour: np.ndarray) -> np.ndarray:
    """uint8 grey image of an RGB one (a grey one as it is): all dense alignment uses of colour, a third the memory."""
    return colour if colour.ndim == 2 else cv2.cvtColor(np.ascontiguousarray(colour), cv2.COLOR_RGB2GRAY)


def check_schedule(iterations: tuple[int, ...], robust_iterations: tuple[int, ...]) -> tuple[list[int], list[int]]:
    """Plain and robust Gauss-Newton steps per pyramid level, coarse to fine (no robust ones: empty), as lists;
    ConfigError unless both count every level and each level gets at least one step."""
    plain = [int(i) for i in iterations]
    robust = [int(i) for i in robust_iterations] or [0] * len(plain)
    if not plain or len(robust) != len(plain) or any(p < 0 or r < 0 or p + r < 1
                                                     for p, r in zip(plain, robust, strict=True)):
        raise ConfigError(f"dense alignment needs a plain and a robust step count per pyramid level (robust ones may "
                          f"be left out), at least one step per level in all, got iterations={iterations!r}, "
                          f"robust_iterations={robust_iterations!r}")
    return plain, robust


class DenseAligner:
    """Aligns RGB-D images of one camera by multi-scale Gauss-Newton, one Open3D ``compute_odometry_result_*``
    step at a time (coarse to fine) over pyramids built once per frame.

    ``scale`` > 1 subsamples the images first (2: a quarter of the pixels, about 4x faster, less accurate);
    ``iterations`` are per pyramid level, coarse to fine; depth beyond ``depth_max`` metres is ignored; ``loss``
    holds Open3D's loss parameters (depth outlier cut-off, depth and intensity Huber widths: metres, and
    intensity in [0, 1]). ``robust_iterations`` (per level, after that level's ``iterations``) use the narrower
    intensity Huber width ``robust_intensity_huber``: the wide one brings the images together from a rough guess,
    the narrow one then stops view-dependent brightness (highlights, exposure, occlusions) from pulling the pose.
    :meth:`semmap.poses.odometry.OdometryConfig.aligner` builds one from a config.
    """

    def __init__(self, intrinsics: CameraIntrinsics, *, iterations: tuple[int, ...], depth_max: float,
                 loss: tuple[float, float, float], method: str = "hybrid", scale: int = 1,
                 robust_iterations: tuple[int, ...] = (), robust_intensity_huber: float = 0.02) -> None:
        if method not in METHODS:
            raise ConfigError(f"dense alignment method must be one of {', '.join(METHODS)}, got {method!r}")
        plain, robust = check_schedule(iterations, robust_iterations)
        if int(scale) < 1 or not depth_max > 0 or not robust_intensity_huber > 0:
            raise ConfigError(f"dense alignment needs scale >= 1, a positive depth_max and robust Huber width, got "
                              f"scale={scale!r}, depth_max={depth_max!r}, "
                              f"robust_intensity_huber={robust_intensity_huber!r}")
        s = int(scale)
        self.scale = s
        self.method = method
        self.depth_max = float(depth_max)
        self.loss = tuple(float(v) for v in loss)
        self.robust_loss = (*self.loss[:2], float(robust_intensity_huber))
        K = intrinsics.K.astype(np.float64).copy()
        if s > 1:
            # colour is area-averaged (new pixel i covers old pixels s*i .. s*i+s-1), depth is subsampled at s*i
            # (a (s-1)/2s-pixel offset; block-averaging depth instead measured about the same on a few pairs)
            K[:2] /= s
            K[:2, 2] -= 0.5 * (1.0 - 1.0 / s)
        self.size = (intrinsics.width // s, intrinsics.height // s)
        self.iterations, self.robust_iterations = plain, robust  # coarse to fine
        self.levels = len(self.iterations)
        self._K = []  # finest first; a coarser level keeps pixel 2i of the finer one, so K halves exactly
        for _ in range(self.levels):
            self._K.append(o3d.core.Tensor(K.copy(), dtype=o3d.core.Dtype.Float64))
            K[:2] /= 2

    def image(self, colour: np.ndarray, depth: np.ndarray) -> DenseImage:
        """A frame's pyramids from its uint8 colour (RGB, or grey as :func:`grey` gives) and depth in metres (0 or
        NaN where invalid)."""
        s = self.scale
        if s > 1:
            w, h = self.size
            colour = cv2.resize(colour[: h * s, : w * s], (w, h), interpolation=cv2.INTER_AREA)
            depth = depth[: h * s : s, : w * s : s]
        gray = grey(colour).astype(np.float32) * (1.0 / 255.0)
        d = np.where((depth > 0) & (depth <= self.depth_max), depth, np.nan).astype(np.float32)
        depths, grays = [d], [gray]
        for _ in range(self.levels - 1):
            depths.append(np.ascontiguousarray(depths[-1][::2, ::2]))
            grays.append(cv2.pyrDown(grays[-1]))
        return DenseImage(depths, grays, self._K)

    def _step(self, source: DenseImage, target: DenseImage, level: int, T: o3d.core.Tensor,
              loss: tuple[float, float, float]):
        trunc, depth_huber, intensity_huber = loss
        K = self._K[level]
        if self.method == "point_to_plane":
            return _ODOMETRY.compute_odometry_result_point_to_plane(
                source.vertex[level], target.vertex[level], target.normals[level], K, T, trunc, depth_huber)
        ddx, ddy, idx, idy = target.gradients[level]
        if self.method == "intensity":
            return _ODOMETRY.compute_odometry_result_intensity(
                source.depth[level], target.depth[level], source.intensity[level], target.intensity[level],
                idx, idy, source.vertex[level], K, T, trunc, intensity_huber)
        return _ODOMETRY.compute_odometry_result_hybrid(
            source.depth[level], target.depth[level], source.intensity[level], target.intensity[level],
            ddx, ddy, idx, idy, source.vertex[level], K, T, trunc, depth_huber, intensity_huber)

    def align(self, source: DenseImage, target: DenseImage, T_init: np.ndarray) -> AlignResult | None:
        """``T_target_source`` from the initial guess ``T_init``, or None when Open3D fails (a singular system,
        e.g. an image without valid depth) or the result is not finite."""
        T = o3d.core.Tensor(np.ascontiguousarray(T_init, np.float64))
        fitness, rmse = 0.0, float("nan")
        schedule = zip(range(self.levels - 1, -1, -1), self.iterations, self.robust_iterations, strict=True)
        try:
            for level, plain, robust in schedule:
                for loss in (self.loss,) * plain + (self.robust_loss,) * robust:
                    step = self._step(source, target, level, T, loss)
                    T = step.transformation.to(o3d.core.Dtype.Float64).matmul(T)
                    fitness, rmse = float(step.fitness), float(step.inlier_rmse)
        except RuntimeError:
            return None
        T_np = T.numpy().astype(np.float64)
        if not np.isfinite(T_np).all():
            return None
        return AlignResult(snap_rigid(T_np), fitness, rmse)
