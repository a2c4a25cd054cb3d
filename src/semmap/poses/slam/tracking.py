"""Frame tracking against the local map: predict with a constant-velocity model, project local landmarks,
match within a search radius, PnP + RANSAC, refine, then match again with the refined pose and refine."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from semmap.poses.slam.config import SlamConfig
from semmap.poses.slam.features import FrameFeatures
from semmap.poses.slam.matching import match_projected
from semmap.poses.slam.pose_solver import PinholeModel, pnp_ransac, refine_pose
from semmap.poses.slam.world_map import SlamMap
from semmap.types import transform_points


@dataclass
class TrackResult:
    """Pose of a tracked frame and its landmark matches (keypoint index -> landmark id), inliers only."""

    T_cw: np.ndarray
    kp: np.ndarray  # (M,) keypoint indices
    lm: np.ndarray  # (M,) landmark ids
    n_visible_lm: np.ndarray  # landmark ids that projected into the image (for the found/visible ratio)

    @property
    def n_inliers(self) -> int:
        return len(self.kp)


class LocalMapTracker:
    """Tracks frames against the landmarks of the keyframes around the current reference keyframe."""

    def __init__(self, smap: SlamMap, cam: PinholeModel, size: tuple[int, int], config: SlamConfig,
                 inv_sigma2: np.ndarray, disp_sigma: float) -> None:
        self.map = smap
        self.cam = cam
        self.size = size
        self.cfg = config
        self.inv_sigma2 = inv_sigma2  # per pyramid level
        self.disp_sigma = disp_sigma  # pixels, of the virtual stereo disparity
        self.local_lm = np.zeros(0, np.int64)
        self._seed = 0

    def set_local_map(self, kf_ids: np.ndarray) -> None:
        """Landmarks of ``kf_ids`` become the local map used by the next frames."""
        self.local_lm = self.map.landmarks_of(np.asarray(kf_ids))

    def project(self, T_cw: np.ndarray, lm_ids: np.ndarray, margin: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """Landmarks of ``lm_ids`` that fall in the image under ``T_cw``: (ids, pixel positions)."""
        pc = transform_points(T_cw, self.map.landmarks.pos[lm_ids])
        front = pc[:, 2] > self.cfg.min_depth * 0.5
        pc, ids = pc[front], lm_ids[front]
        uv, _ = self.cam.project(pc)
        w, h = self.size
        inside = (uv[:, 0] >= -margin) & (uv[:, 0] < w + margin) & (uv[:, 1] >= -margin) & (uv[:, 1] < h + margin)
        return ids[inside], uv[inside]

    def _match(self, feats: FrameFeatures, T_cw: np.ndarray, lm_ids: np.ndarray,
               radius: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        ids, proj = self.project(T_cw, lm_ids)
        desc64 = self.map.landmarks.desc[ids].view(np.uint64)
        q, t = match_projected(proj, desc64, feats.uv, feats.desc64, radius, self.size,
                               self.cfg.max_descriptor_distance, self.cfg.match_ratio)
        return ids[q], t, ids

    def _refine(self, feats: FrameFeatures, T_cw: np.ndarray, lm: np.ndarray,
                kp: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        pts = self.map.landmarks.pos[lm]
        return refine_pose(T_cw, pts, feats.uv[kp], feats.ur[kp], self.inv_sigma2[feats.octave[kp]], self.cam,
                           self.disp_sigma)

    def track(self, feats: FrameFeatures, T_cw_pred: np.ndarray, radius_scale: float = 1.0,
              lm_ids: np.ndarray | None = None, first_ids: np.ndarray | None = None) -> TrackResult | None:
        """Pose of a frame given a predicted pose, or None when too few landmarks agree.

        The wide first search uses ``first_ids`` (e.g. the landmarks the last frame matched: few, so cheap) when
        given, else the whole local map ``lm_ids``; the tight second search always uses the whole local map.
        """
        cfg = self.cfg
        lm_ids = self.local_lm if lm_ids is None else lm_ids
        if len(lm_ids) < cfg.min_tracked or len(feats) < cfg.min_tracked:
            return None
        first = lm_ids if first_ids is None or len(first_ids) < 2 * cfg.min_tracked else first_ids
        lm, kp, _ = self._match(feats, T_cw_pred, first, cfg.search_radius * radius_scale)
        if len(lm) < cfg.min_tracked:
            return None
        self._seed += 1
        found = pnp_ransac(self.map.landmarks.pos[lm], feats.uv[kp], self.cam, T_cw_pred,
                           cfg.ransac_reprojection_error, cfg.ransac_iterations, seed=self._seed)
        if found is None or found[1].sum() < cfg.min_tracked:
            return None
        T, inl = found
        T, ok = self._refine(feats, T, lm[inl], kp[inl])
        if ok.sum() < cfg.min_tracked:
            return None
        # second pass: the refined pose predicts well, so a tight radius finds more matches
        lm, kp, visible = self._match(feats, T, lm_ids, max(3.0, cfg.search_radius / 3))
        if len(lm) < cfg.min_tracked:
            return None
        T2, ok = self._refine(feats, T, lm, kp)
        if ok.sum() < cfg.min_tracked:
            return None
        return TrackResult(T2, kp[ok], lm[ok], visible)
