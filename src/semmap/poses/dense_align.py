"""Dense RGB-D alignment (photometric + geometric Gauss-Newton) over image pyramids that are built once per frame.

Each step's normal equations come from the numba kernels of :mod:`semmap.poses.dense_kernels`: bilinear (sub-pixel)
reads of the target, per-pixel image gradients, and sums that do not depend on thread scheduling, so an alignment
gives the same pose on every run. A tracker aligns many frames to one keyframe, so each frame is prepared once
(:meth:`DenseAligner.image`) and a target keeps its gradients.

Open3D's tensor odometry steps did this before (see DESIGN); they read the target at the nearest pixel and their
sums change with thread timing. Same frames, same settings: about half the pose error on the simulated sequences.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from semmap.errors import ConfigError
from semmap.poses.dense_kernels import increment, photometric_geometric_system, point_to_plane_system
from semmap.types import CameraIntrinsics, snap_rigid

#: A plain step that changes the pose by less than this (largest matrix entry: metres, or radians for small
#: rotations) ends its pyramid level early, robust steps included: running those after convergence measured the same
#: ATEs and cost 10-12 ms per frame on the simulated loop (see DESIGN).
CONVERGED = 1e-4
#: Cost functions: photometric + geometric, photometric only, geometric only.
METHODS = ("hybrid", "intensity", "point_to_plane")


@dataclass(frozen=True)
class AlignResult:
    """A dense alignment: ``T_target_source``, the fraction of pixels with a correspondence, and the RMSE of their
    (weighted) residuals."""

    T: np.ndarray
    fitness: float
    inlier_rmse: float


def _gradient(image: np.ndarray, dx: int, dy: int) -> np.ndarray:
    """Per-pixel derivative (3x3 Sobel divided by its weight 8); NaN next to invalid depth."""
    return cv2.Sobel(image, cv2.CV_32F, dx, dy, ksize=3, scale=0.125, borderType=cv2.BORDER_REPLICATE)


def _vertex_map(depth: np.ndarray, K: np.ndarray) -> np.ndarray:
    """(H, W, 3) float32 camera-frame points of a depth image (NaN where the depth is)."""
    fx, fy, cx, cy = K
    h, w = depth.shape
    x = (np.arange(w, dtype=np.float32) - np.float32(cx)) / np.float32(fx)
    y = (np.arange(h, dtype=np.float32) - np.float32(cy)) / np.float32(fy)
    return np.stack([depth * x[None, :], depth * y[:, None], depth], axis=2)


class DenseImage:
    """One frame prepared for dense alignment: float32 depth (NaN invalid), intensity in [0, 1] and vertex-map
    pyramids (finest level first), plus what a target needs (image gradients, normals), computed on first use as a
    target and kept."""

    def __init__(self, depth: list[np.ndarray], intensity: list[np.ndarray], K: list[np.ndarray]) -> None:
        self.depth = depth
        self.intensity = intensity
        self.vertex = [_vertex_map(d, k) for d, k in zip(depth, K, strict=True)]
        self._gradients: list[tuple[np.ndarray, ...]] | None = None
        self._normals: list[np.ndarray] | None = None

    @property
    def gradients(self) -> list[tuple[np.ndarray, ...]]:
        """Per level: (depth dx, depth dy, intensity dx, intensity dy) per-pixel gradients."""
        if self._gradients is None:
            self._gradients = [(_gradient(d, 1, 0), _gradient(d, 0, 1), _gradient(i, 1, 0), _gradient(i, 0, 1))
                               for d, i in zip(self.depth, self.intensity, strict=True)]
        return self._gradients

    @property
    def normals(self) -> list[np.ndarray]:
        """Per level: the normal map of the vertex map (point-to-plane targets only)."""
        if self._normals is None:
            self._normals = [_normal_map(v) for v in self.vertex]
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
    """Aligns RGB-D images of one camera by multi-scale Gauss-Newton (coarse to fine) over pyramids built once per
    frame.

    ``scale`` > 1 subsamples the images first (2: a quarter of the pixels, about 4x faster, less accurate);
    ``iterations`` are per pyramid level, coarse to fine; depth beyond ``depth_max`` metres is ignored; ``loss``
    holds the loss parameters (depth outlier cut-off, depth and intensity Huber widths: metres, and intensity in
    [0, 1]); ``depth_weight`` scales the depth residual (metres) against the intensity one in the hybrid cost.
    ``robust_iterations`` (per level, after that level's ``iterations``) use the narrower intensity Huber width
    ``robust_intensity_huber``: the wide one brings the images together from a rough guess, the narrow one then stops
    view-dependent brightness (highlights, exposure, occlusions) from pulling the pose.
    :meth:`semmap.poses.odometry.OdometryConfig.aligner` builds one from a config.
    """

    def __init__(self, intrinsics: CameraIntrinsics, *, iterations: tuple[int, ...], depth_max: float,
                 loss: tuple[float, float, float], method: str = "hybrid", scale: int = 1,
                 robust_iterations: tuple[int, ...] = (), robust_intensity_huber: float = 0.02,
                 depth_weight: float = 1.0) -> None:
        if method not in METHODS:
            raise ConfigError(f"dense alignment method must be one of {', '.join(METHODS)}, got {method!r}")
        plain, robust = check_schedule(iterations, robust_iterations)
        if int(scale) < 1 or not depth_max > 0 or not robust_intensity_huber > 0 or not depth_weight > 0:
            raise ConfigError(f"dense alignment needs scale >= 1, a positive depth_max, robust Huber width and depth "
                              f"weight, got scale={scale!r}, depth_max={depth_max!r}, "
                              f"robust_intensity_huber={robust_intensity_huber!r}, depth_weight={depth_weight!r}")
        s = int(scale)
        self.scale = s
        self.method = method
        self.depth_max = float(depth_max)
        self.depth_weight = float(depth_weight)
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
        self._K = []  # finest first, (fx, fy, cx, cy); a coarser level keeps pixel 2i of the finer one, so K halves
        for _ in range(self.levels):
            self._K.append(np.array([K[0, 0], K[1, 1], K[0, 2], K[1, 2]]))
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

    def _step(self, source: DenseImage, target: DenseImage, level: int, T: np.ndarray,
              loss: tuple[float, float, float]) -> tuple[np.ndarray, float, float] | None:
        """One Gauss-Newton step at pyramid ``level`` from ``T``: the new ``T``, fitness and residual RMSE, or None
        when the system is singular."""
        trunc, depth_huber, intensity_huber = loss
        K = self._K[level]
        if self.method == "point_to_plane":
            system = point_to_plane_system(source.vertex[level], target.vertex[level], target.normals[level], K, T,
                                           trunc, depth_huber)
        else:
            depth_weight = self.depth_weight if self.method == "hybrid" else 0.0
            system = photometric_geometric_system(
                source.vertex[level], source.intensity[level], target.depth[level], target.intensity[level],
                *target.gradients[level], K, T, trunc, depth_huber, intensity_huber, depth_weight, 1.0)
        step = increment(system)
        if step is None:
            return None
        count = system[28]
        return step @ T, count / source.intensity[level].size, float(np.sqrt(system[27] / count))

    def align(self, source: DenseImage, target: DenseImage, T_init: np.ndarray) -> AlignResult | None:
        """``T_target_source`` from the initial guess ``T_init``, or None when a step's system is singular (e.g. an
        image without valid depth) or the result is not finite."""
        T = np.array(T_init, dtype=np.float64)
        fitness, rmse = 0.0, float("nan")
        schedule = zip(range(self.levels - 1, -1, -1), self.iterations, self.robust_iterations, strict=True)
        for level, plain, robust in schedule:
            for i, loss in enumerate((self.loss,) * plain + (self.robust_loss,) * robust):
                out = self._step(source, target, level, T, loss)
                if out is None:
                    return None
                moved = np.abs(out[0] - T).max()
                T, fitness, rmse = out
                if moved < CONVERGED and i < plain:  # converged: the level ends here
                    break
        if not np.isfinite(T).all():
            return None
        return AlignResult(snap_rigid(T), fitness, rmse)
