"""ORB keypoints spread over a grid, their descriptors and their depth (with a depth-edge check)."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from semmap.poses.slam.config import SlamConfig
from semmap.types import CameraIntrinsics


@dataclass
class FrameFeatures:
    """Keypoints of one image: pixel positions, pyramid level, descriptor, depth and camera-frame point."""

    uv: np.ndarray  # (N, 2) float64 pixels
    octave: np.ndarray  # (N,) int32 pyramid level
    desc: np.ndarray  # (N, 32) uint8 ORB descriptors
    depth: np.ndarray  # (N,) float64 metres, 0 where the depth is missing or unreliable
    xyz: np.ndarray  # (N, 3) float64 back-projected points (camera frame), 0 where depth is 0
    ur: np.ndarray  # (N,) float64 virtual right-image u (u - fx*b/z), NaN where depth is 0
    response: np.ndarray  # (N,) float32 corner strength

    def __len__(self) -> int:
        return len(self.uv)

    @property
    def has_depth(self) -> np.ndarray:
        return self.depth > 0

    @property
    def desc64(self) -> np.ndarray:
        """Descriptors viewed as (N, 4) uint64 words for fast Hamming distances."""
        return self.desc.view(np.uint64)

    def strongest(self, n: int) -> np.ndarray:
        """Indices of the ``n`` keypoints with the strongest corner response."""
        return np.argsort(-self.response, kind="stable")[:n]

    @classmethod
    def empty(cls) -> FrameFeatures:
        return cls(np.zeros((0, 2)), np.zeros(0, np.int32), np.zeros((0, 32), np.uint8), np.zeros(0),
                   np.zeros((0, 3)), np.zeros(0), np.zeros(0, np.float32))


#: metres; depth becomes a virtual right-image coordinate ``u - fx * b / z`` (only sets units, see depth_noise)
VIRTUAL_BASELINE = 0.08


class OrbExtractor:
    """Detects ORB keypoints evenly over the image and attaches depth to each (one per frame, reused)."""

    def __init__(self, config: SlamConfig, intrinsics: CameraIntrinsics) -> None:
        self.config = config
        self.cam = intrinsics
        self.bf = VIRTUAL_BASELINE * intrinsics.fx
        # detect more than needed, then keep the strongest per grid cell so corners do not cluster
        self._orb = cv2.ORB_create(nfeatures=int(config.n_features * 2), scaleFactor=config.scale_factor,
                                   nlevels=config.n_levels, edgeThreshold=19, patchSize=31,
                                   fastThreshold=config.fast_threshold)
        self.sigma2 = config.scale_factor ** (2 * np.arange(config.n_levels))  # pixel variance per level

    def extract(self, rgb: np.ndarray, depth: np.ndarray) -> FrameFeatures:
        """Keypoints, descriptors and depth of one RGB-D image."""
        gray = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
        kps = self._orb.detect(gray, None)
        if not kps:
            return FrameFeatures.empty()
        kps = self._spread(kps)
        kps, desc = self._orb.compute(gray, kps)
        if desc is None or not kps:
            return FrameFeatures.empty()
        uv = np.array([k.pt for k in kps], np.float64)
        octave = np.array([k.octave for k in kps], np.int32)
        uv = self._level_to_image(uv, octave)
        response = np.array([k.response for k in kps], np.float32)
        if self.config.subpixel:
            uv = self._subpixel(gray, uv, octave)
        d = self._keypoint_depth(depth, uv)
        cam = self.cam
        xyz = np.zeros((len(uv), 3))
        xyz[:, 0] = (uv[:, 0] - cam.cx) * d / cam.fx
        xyz[:, 1] = (uv[:, 1] - cam.cy) * d / cam.fy
        xyz[:, 2] = d
        with np.errstate(divide="ignore"):
            ur = np.where(d > 0, uv[:, 0] - self.bf / np.where(d > 0, d, 1.0), np.nan)
        return FrameFeatures(uv, octave, np.ascontiguousarray(desc), d, xyz, ur, response)

    def _spread(self, kps: list) -> list:
        """At most ``n_features`` keypoints: the strongest of each grid cell first, then the strongest overall."""
        n = self.config.n_features
        if len(kps) <= n:
            return list(kps)
        gx, gy = self.config.grid_cells
        pts = np.array([k.pt for k in kps])
        resp = np.array([k.response for k in kps])
        cell = (np.minimum((pts[:, 1] * gy / self.cam.height).astype(int), gy - 1) * gx
                + np.minimum((pts[:, 0] * gx / self.cam.width).astype(int), gx - 1))
        order = np.lexsort((-resp, cell))
        sorted_cell = cell[order]
        first = np.searchsorted(sorted_cell, sorted_cell, side="left")
        rank = np.empty(len(kps), np.int64)
        rank[order] = np.arange(len(kps)) - first  # rank of each keypoint inside its cell
        per_cell = max(1, n // (gx * gy))
        # keypoints ranked by (rank within cell capped at per_cell, then response): cells fill evenly first
        key = np.lexsort((-resp, np.minimum(rank, per_cell)))
        return [kps[i] for i in key[:n]]

    def _level_to_image(self, uv: np.ndarray, octave: np.ndarray) -> np.ndarray:
        """Full-resolution pixel positions of keypoints found on coarser pyramid levels.

        OpenCV reports a level-``l`` keypoint as its level position times the nominal scale s^l, which ignores
        pixel centres and the rounded level size: up to 1.3 px off at level 7, and off by a different amount
        at each level, so a landmark seen at another level than it was made at gets a biased observation.
        Each level is the one before resized to ``round(size / s^l)``; the pixel-centre mappings of those
        resizes compose, so a level pixel centre x lies at (x + 0.5) * size / level_size - 0.5."""
        s = self.config.scale_factor ** octave.astype(np.float64)[:, None]
        size = np.array([self.cam.width, self.cam.height], np.float64)
        level_size = np.floor(size / s + 0.5)
        return (uv / s + 0.5) * (size / level_size) - 0.5

    def _subpixel(self, gray: np.ndarray, uv: np.ndarray, octave: np.ndarray) -> np.ndarray:
        """Keypoints of the finer pyramid levels moved to the sub-pixel corner position (FAST corners sit on
        the integer grid of their level); a keypoint that would move too far keeps its position."""
        out = uv.copy()
        crit = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_COUNT, 10, 0.01)
        for level in range(min(3, self.config.n_levels)):
            sel = np.flatnonzero(octave == level)
            if len(sel) == 0:
                continue
            half = 2 + level
            pts = np.ascontiguousarray(uv[sel].astype(np.float32).reshape(-1, 1, 2))
            ref = cv2.cornerSubPix(gray, pts, (half, half), (-1, -1), crit).reshape(-1, 2)
            ok = np.isfinite(ref).all(1) & (np.abs(ref - uv[sel]).max(1) <= 0.75 * self.config.scale_factor**level)
            out[sel[ok]] = ref[ok]
        return out

    def _keypoint_depth(self, depth: np.ndarray, uv: np.ndarray) -> np.ndarray:
        """Depth at each keypoint, 0 when missing, out of range or near a depth discontinuity (where colour and
        depth that are only roughly registered disagree most)."""
        cfg = self.config
        h, w = depth.shape
        r = cfg.depth_edge_radius
        x = np.clip(np.rint(uv[:, 0]).astype(int), r, w - 1 - r)
        y = np.clip(np.rint(uv[:, 1]).astype(int), r, h - 1 - r)
        # (2r+1)^2 neighbourhood of each keypoint, gathered with fancy indexing (no image-wide filtering)
        oy, ox = np.mgrid[-r:r + 1, -r:r + 1]
        patch = depth[y[:, None] + oy.ravel()[None], x[:, None] + ox.ravel()[None]].astype(np.float64)
        d = patch[:, patch.shape[1] // 2]
        valid = (patch > 0).all(1) & (d >= cfg.min_depth) & (d <= cfg.max_depth)
        spread = patch.max(1) - patch.min(1)
        valid &= spread <= cfg.depth_edge_ratio * np.maximum(d, 1e-6)
        return np.where(valid, d, 0.0)
