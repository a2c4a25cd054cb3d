"""A user's own arrays as semmap's inputs: one RGB-D frame and its per-pixel classes from a driver or a ROS 2 node.

:func:`frame_from_arrays` checks and converts colour, depth in metres, intrinsics and pose into a
:class:`~semmap.types.Frame`; :func:`class_sets` turns a class-id image, dense class probabilities or a ready
:class:`~semmap.types.TopKProbs` into the per-pixel class sets the maps fuse.  ``Mapper.integrate_arrays`` uses both.
"""

from __future__ import annotations

import numpy as np

from semmap.errors import ConfigError
from semmap.types import CameraIntrinsics, Frame, TopKProbs


def frame_from_arrays(rgb: np.ndarray, depth_m: np.ndarray, intrinsics: CameraIntrinsics | np.ndarray, *,
                      T_world_cam: np.ndarray | None = None, index: int = 0, timestamp: float = 0.0) -> Frame:
    """A :class:`~semmap.types.Frame` of colour (H, W, 3) uint8, depth (H, W) in metres (0, NaN or inf =
    invalid), intrinsics (a ``CameraIntrinsics`` or a 3x3 camera matrix) and an optional 4x4 camera-to-world pose."""
    rgb, depth = np.asarray(rgb), np.asarray(depth_m)
    if depth.ndim != 2 or not np.issubdtype(depth.dtype, np.floating):
        raise ConfigError(f"depth must be an (H, W) float array in metres, got {depth.shape} {depth.dtype}")
    if rgb.shape != (*depth.shape, 3) or rgb.dtype != np.uint8:
        raise ConfigError(f"colour must be ({depth.shape[0]}, {depth.shape[1]}, 3) uint8 like the depth image, "
                          f"got {rgb.shape} {rgb.dtype}")
    if not isinstance(intrinsics, CameraIntrinsics):
        K = np.asarray(intrinsics, np.float64)
        if K.shape != (3, 3):
            raise ConfigError(f"intrinsics must be a CameraIntrinsics or a 3x3 camera matrix, got {K.shape}")
        intrinsics = CameraIntrinsics.from_matrix(K, depth.shape[1], depth.shape[0])
    elif (intrinsics.height, intrinsics.width) != depth.shape:
        raise ConfigError(f"intrinsics are for {intrinsics.width}x{intrinsics.height} images, depth is "
                          f"{depth.shape[1]}x{depth.shape[0]}")
    depth = np.where(np.isfinite(depth) & (depth > 0), depth, 0.0).astype(np.float32)
    pose = None if T_world_cam is None else np.asarray(T_world_cam, np.float64)
    return Frame(int(index), float(timestamp), np.ascontiguousarray(rgb), depth, intrinsics, T_world_cam=pose)


def class_sets(semantics: np.ndarray | TopKProbs | None, shape: tuple[int, int], *, num_classes: int | None,
               k: int = 3, label_confidence: float = 0.9) -> TopKProbs | None:
    """Per-pixel top-``k`` class sets (H, W, k) from a class-id image (H, W) (each pixel's class at
    ``label_confidence``), dense class probabilities (H, W, K) or a ``TopKProbs`` (H, W, k), passed through."""
    if semantics is None:
        return None
    if isinstance(semantics, TopKProbs):
        if semantics.labels.shape[:2] != shape or semantics.labels.ndim != 3:
            raise ConfigError(f"class sets must be ({shape[0]}, {shape[1]}, k), got {semantics.labels.shape}")
        return semantics
    a = np.asarray(semantics)
    if a.ndim == 2 and a.shape == shape and np.issubdtype(a.dtype, np.integer):
        if num_classes is None:
            raise ConfigError("class labels need a map with a label set (pass label_set= to the map)")
        if a.size and int(a.min()) < 0:
            raise ConfigError(f"class labels must be ids 0..{num_classes - 1}, got {int(a.min())}")
        return TopKProbs.from_hard_labels(a, label_confidence, num_classes, k)
    if a.ndim == 3 and a.shape[:2] == shape and np.issubdtype(a.dtype, np.floating):
        if num_classes is not None and a.shape[2] != num_classes:
            raise ConfigError(f"class probabilities have {a.shape[2]} classes, the map's label set {num_classes}")
        if not np.isfinite(a).all() or (a < 0).any():
            raise ConfigError("class probabilities must be finite and non-negative")
        return TopKProbs.from_dense(a, k)
    raise ConfigError(f"semantics must be a ({shape[0]}, {shape[1]}) integer class-id image, ({shape[0]}, "
                      f"{shape[1]}, K) float class probabilities or TopKProbs, got {a.shape} {a.dtype}")
