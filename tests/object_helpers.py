"""Synthetic object scenes for object-map tests: boxes standing on a floor, ray cast analytically (fast, exact)."""

from __future__ import annotations

import numpy as np

from semmap.types import CameraIntrinsics, Frame, make_pose

OBJECT_CAMERA = CameraIntrinsics(160, 120, 130.0, 130.0, 79.5, 59.5)


def look_at(eye: np.ndarray, target: np.ndarray) -> np.ndarray:
    """``T_world_cam`` of a camera at ``eye`` looking at ``target`` (world z up, image y down)."""
    z = np.asarray(target, float) - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return make_pose(np.column_stack([x, y, z]), eye)


def render_boxes(boxes: list[tuple[np.ndarray, np.ndarray]], T_wc: np.ndarray,
                 cam: CameraIntrinsics = OBJECT_CAMERA) -> tuple[np.ndarray, np.ndarray]:
    """Depth (H, W) float32 and instance ids (H, W) int32 (box i -> i + 1; the floor z = 0 gets 0) of axis-aligned
    boxes ``(min corner, max corner)`` seen from ``T_wc``."""
    u, v = np.meshgrid(np.arange(cam.width), np.arange(cam.height))
    d_cam = np.stack([(u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, np.ones_like(u, float)], -1).reshape(-1, 3)
    d = d_cam @ T_wc[:3, :3].T
    o = T_wc[:3, 3]
    best = np.full(len(d), np.inf)
    ids = np.zeros(len(d), np.int32)
    with np.errstate(divide="ignore", invalid="ignore"):
        t_floor = np.where(d[:, 2] < 0, -o[2] / d[:, 2], np.inf)
        for i, (lo, hi) in enumerate(boxes):
            t1, t2 = (lo - o) / d, (hi - o) / d
            near = np.nanmax(np.minimum(t1, t2), axis=1)
            far = np.nanmin(np.maximum(t1, t2), axis=1)
            hit = (near <= far) & (near > 0) & (near < best)
            best[hit] = near[hit]
            ids[hit] = i + 1
    floor = t_floor < best
    best[floor] = t_floor[floor]
    ids[floor] = 0
    depth = np.where(np.isfinite(best), best, 0.0).astype(np.float32)  # ray length at unit z = depth
    return depth.reshape(cam.height, cam.width), ids.reshape(cam.height, cam.width)


def box_frames(boxes, classes, n: int, *, radius: float = 2.2, height: float = 1.2, arc_deg: float = 90.0,
               start_deg: float = -45.0, cam: CameraIntrinsics = OBJECT_CAMERA) -> list[Frame]:
    """``n`` frames of a camera on an arc around the boxes' middle, with depth, labels, instances and poses."""
    centre = np.mean([(lo + hi) / 2 for lo, hi in boxes], axis=0)
    frames = []
    for i in range(n):
        a = np.radians(start_deg + arc_deg * i / max(n - 1, 1))
        eye = centre + np.array([radius * np.cos(a), radius * np.sin(a), height - centre[2]])
        T = look_at(eye, centre)
        depth, inst = render_boxes(boxes, T, cam)
        labels = np.where(inst > 0, np.asarray([0, *classes])[inst], 2).astype(np.uint16)  # floor: class 2
        rgb = np.zeros((cam.height, cam.width, 3), np.uint8)
        rgb[..., 0] = (inst * 53) % 256
        rgb[..., 1] = (inst * 97) % 256
        frames.append(Frame(i, i / 30, rgb, depth, cam, T, labels=labels, instances=inst, name=f"{i:04d}"))
    return frames
