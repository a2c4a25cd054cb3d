"""Frames as Open3D RGB-D images (tensor and legacy API), shared by the dense odometry and its Open3D peers.

A :class:`~semmap.types.Frame` holds depth as float32 metres (0 = invalid); both images keep metres, so the
Open3D calls that take a depth scale must be given ``DEPTH_SCALE`` (1.0), not their default of 1000 (mm).
"""

from __future__ import annotations

import numpy as np
import open3d as o3d

from semmap.types import CameraIntrinsics, Frame

#: Stored depth units per metre of the images built here (depth stays in metres).
DEPTH_SCALE = 1.0


def tensor_rgbd(frame: Frame) -> o3d.t.geometry.RGBDImage:
    """Tensor RGB-D image of a frame: uint8 RGB colour and float32 depth in metres (0 invalid)."""
    color = o3d.t.geometry.Image(o3d.core.Tensor(np.ascontiguousarray(frame.rgb)))
    depth = o3d.t.geometry.Image(o3d.core.Tensor(np.ascontiguousarray(frame.depth, dtype=np.float32)))
    return o3d.t.geometry.RGBDImage(color, depth)


def tensor_intrinsics(camera: CameraIntrinsics) -> o3d.core.Tensor:
    """3x3 float64 camera matrix as an Open3D tensor."""
    return o3d.core.Tensor(camera.K, dtype=o3d.core.Dtype.Float64)


def legacy_rgbd(frame: Frame, depth_trunc: float = 3.0) -> o3d.geometry.RGBDImage:
    """Legacy RGB-D image (intensity + float depth in metres, zero beyond ``depth_trunc``) of a frame."""
    color = o3d.geometry.Image(np.ascontiguousarray(frame.rgb))
    depth = o3d.geometry.Image(np.ascontiguousarray(frame.depth, dtype=np.float32))
    return o3d.geometry.RGBDImage.create_from_color_and_depth(
        color, depth, depth_scale=DEPTH_SCALE, depth_trunc=depth_trunc, convert_rgb_to_intensity=True)


def legacy_intrinsics(camera: CameraIntrinsics) -> o3d.camera.PinholeCameraIntrinsic:
    """Legacy pinhole intrinsics of a camera."""
    return o3d.camera.PinholeCameraIntrinsic(camera.width, camera.height, camera.fx, camera.fy, camera.cx, camera.cy)
