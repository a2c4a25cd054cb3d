"""Dense (photometric + geometric) frame-to-keyframe alignment for the SLAM: a fallback where features fail
(a textureless wall filling the view) and an optional refinement of each feature-tracked pose.

Images are aligned with Open3D's tensor hybrid RGB-D odometry steps over pyramids built once per frame, at half
resolution by default (``dense_scale``): ~1.5 ms to prepare a frame and ~8 ms per alignment at 320x240.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
import open3d as o3d

from semmap.poses.odometry import OdometryConfig
from semmap.poses.slam import se3
from semmap.poses.slam.config import SlamConfig
from semmap.types import CameraIntrinsics

_ODOMETRY = o3d.t.pipelines.odometry
#: Open3D loss parameters (depth outlier cut-off, Huber widths): the dense odometry's defaults, one definition
_LOSS = OdometryConfig()


@dataclass(frozen=True)
class DenseResult:
    """A dense alignment: ``T_target_source`` and the fraction of pixels with a correspondence."""

    T: np.ndarray
    fitness: float


def _tensor(a: np.ndarray) -> o3d.core.Tensor:
    return o3d.core.Tensor(np.ascontiguousarray(a, np.float32))


class DenseImage:
    """One frame prepared for dense alignment: depth (NaN invalid), intensity and vertex-map pyramids (finest
    level first), plus the gradient pyramids a target needs (computed on first use as a target, then kept: a
    keyframe is the target of many frames, and Open3D's one-call multi-scale odometry would rebuild them each time).
    """

    def __init__(self, depth: list[np.ndarray], intensity: list[np.ndarray], K: list[o3d.core.Tensor]) -> None:
        self.depth = [_tensor(d[..., None]) for d in depth]
        self.intensity = [_tensor(i[..., None]) for i in intensity]
        self.vertex = [o3d.t.geometry.Image(d).create_vertex_map(k, float("nan")).as_tensor()
                       for d, k in zip(self.depth, K, strict=True)]
        self._gradients: list[tuple[o3d.core.Tensor, ...]] | None = None

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


class DenseAligner:
    """Aligns RGB-D images of one camera by multi-scale hybrid (photometric + geometric) Gauss-Newton, one
    Open3D ``compute_odometry_result_hybrid`` step at a time over image pyramids that are built once per frame."""

    def __init__(self, config: SlamConfig, intrinsics: CameraIntrinsics) -> None:
        self.config = config
        s = int(config.dense_scale)
        self.scale = s
        K = intrinsics.K.astype(np.float64).copy()
        if s > 1:
            # colour is area-averaged (new pixel i covers old pixels s*i .. s*i+s-1), depth is subsampled at s*i
            # (a (s-1)/2s-pixel offset; block-averaging depth instead measured about the same on a few pairs)
            K[:2] /= s
            K[:2, 2] -= 0.5 * (1.0 - 1.0 / s)
        self.size = (intrinsics.width // s, intrinsics.height // s)
        self.iterations = [int(i) for i in config.dense_iterations]  # coarse to fine
        self.levels = len(self.iterations)
        self._K = []  # finest first; a coarser level keeps pixel 2i of the finer one, so K halves exactly
        for _ in range(self.levels):
            self._K.append(o3d.core.Tensor(K.copy(), dtype=o3d.core.Dtype.Float64))
            K[:2] /= 2

    def image(self, rgb: np.ndarray, depth: np.ndarray) -> DenseImage:
        """A frame's pyramids; depth in metres, 0 where invalid."""
        s = self.scale
        if s > 1:
            w, h = self.size
            rgb = cv2.resize(rgb[: h * s, : w * s], (w, h), interpolation=cv2.INTER_AREA)
            depth = depth[: h * s : s, : w * s : s]
        gray = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2GRAY).astype(np.float32) * (1.0 / 255.0)
        d = np.where((depth > 0) & (depth <= self.config.max_depth), depth, np.nan).astype(np.float32)
        depths, grays = [d], [gray]
        for _ in range(self.levels - 1):
            depths.append(np.ascontiguousarray(depths[-1][::2, ::2]))
            grays.append(cv2.pyrDown(grays[-1]))
        return DenseImage(depths, grays, self._K)

    def align(self, source: DenseImage, target: DenseImage, T_init: np.ndarray) -> DenseResult | None:
        """``T_target_source`` from the initial guess ``T_init``, or None when Open3D fails or the result is not
        finite."""
        T = o3d.core.Tensor(np.ascontiguousarray(T_init, np.float64))
        grads = target.gradients
        fitness = 0.0
        try:
            for level, iterations in zip(range(self.levels - 1, -1, -1), self.iterations, strict=True):
                ddx, ddy, idx, idy = grads[level]
                for _ in range(iterations):
                    step = _ODOMETRY.compute_odometry_result_hybrid(
                        source.depth[level], target.depth[level], source.intensity[level], target.intensity[level],
                        ddx, ddy, idx, idy, source.vertex[level], self._K[level], T,
                        _LOSS.depth_outlier_trunc, _LOSS.depth_huber_delta, _LOSS.intensity_huber_delta)
                    T = step.transformation.to(o3d.core.Dtype.Float64).matmul(T)
                    fitness = float(step.fitness)
        except RuntimeError:  # a singular system ("tracking failed"), e.g. an image without valid depth
            return None
        T_np = T.numpy().astype(np.float64)
        if not np.isfinite(T_np).all():
            return None
        return DenseResult(se3.orthonormalise(T_np), fitness)

