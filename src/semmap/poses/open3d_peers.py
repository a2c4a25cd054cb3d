"""Open3D's RGB-D odometry used plainly, as its documentation shows, chained frame to frame: the benchmark peers.

``open3d-f2f`` is the legacy ``compute_rgbd_odometry`` with the hybrid Jacobian and default options;
``open3d-f2f-tensor`` is the tensor ``rgbd_odometry_multi_scale`` with the hybrid method and default
parameters. Neither uses a motion model; a failed step keeps the previous pose.
"""

from __future__ import annotations

import numpy as np
import open3d as o3d

from semmap.poses.o3d_images import DEPTH_SCALE, legacy_intrinsics, legacy_rgbd, tensor_intrinsics, tensor_rgbd
from semmap.types import Frame, Trajectory, orthonormalize


class _Chain:
    """Poses built by chaining relative motions from the previous frame."""

    name = ""

    def __init__(self) -> None:
        self._prev = None
        self._stamps: list[float] = []
        self._poses: list[np.ndarray] = []
        self._names: list[str] = []
        self.failures = 0

    def _step(self, frame: Frame, image) -> np.ndarray | None:
        """Motion T_prev_cur (source = current, target = previous), None when Open3D reports failure."""
        raise NotImplementedError

    def _image(self, frame: Frame):
        raise NotImplementedError

    def track(self, frame: Frame) -> np.ndarray:
        image = self._image(frame)
        if self._prev is None:
            pose = np.eye(4)
        else:
            step = self._step(frame, image)
            if step is None or not np.isfinite(step).all():
                self.failures += 1
                step = np.eye(4)
            pose = self._poses[-1] @ step
            pose[:3, :3] = orthonormalize(pose[:3, :3])  # keep the chained product a rotation
        self._prev = image
        self._stamps.append(frame.timestamp)
        self._poses.append(pose)
        self._names.append(frame.name or str(frame.index))
        return pose

    def trajectory(self) -> Trajectory:
        return Trajectory(np.asarray(self._stamps), np.asarray(self._poses).reshape(-1, 4, 4), tuple(self._names))


class Open3dLegacyOdometry(_Chain):
    """Legacy ``compute_rgbd_odometry`` (hybrid Jacobian, default ``OdometryOption``), frame to frame."""

    name = "open3d-f2f"

    def __init__(self) -> None:
        super().__init__()
        self._intrinsic = None
        self._jacobian = o3d.pipelines.odometry.RGBDOdometryJacobianFromHybridTerm()
        self._option = o3d.pipelines.odometry.OdometryOption()

    def _image(self, frame: Frame) -> o3d.geometry.RGBDImage:
        if self._intrinsic is None:
            self._intrinsic = legacy_intrinsics(frame.intrinsics)
        return legacy_rgbd(frame)

    def _step(self, frame: Frame, image) -> np.ndarray | None:
        ok, T, _ = o3d.pipelines.odometry.compute_rgbd_odometry(
            image, self._prev, self._intrinsic, np.eye(4), self._jacobian, self._option)
        return np.asarray(T) if ok else None


class Open3dTensorOdometry(_Chain):
    """Tensor ``rgbd_odometry_multi_scale`` (hybrid, default parameters), frame to frame."""

    name = "open3d-f2f-tensor"

    def __init__(self) -> None:
        super().__init__()
        self._K = None

    def _image(self, frame: Frame) -> o3d.t.geometry.RGBDImage:
        if self._K is None:
            self._K = tensor_intrinsics(frame.intrinsics)
        return tensor_rgbd(frame)

    def _step(self, frame: Frame, image) -> np.ndarray | None:
        try:
            result = o3d.t.pipelines.odometry.rgbd_odometry_multi_scale(
                image, self._prev, self._K, depth_scale=DEPTH_SCALE,
                method=o3d.t.pipelines.odometry.Method.Hybrid)
        except RuntimeError:  # a singular system: Open3D reports "tracking failed"
            return None
        return result.transformation.numpy()
