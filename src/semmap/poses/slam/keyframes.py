"""Keyframe selection, keyframe creation (new landmarks from unmatched keypoints with depth) and landmark culling."""

from __future__ import annotations

import numpy as np

from semmap.poses.slam.config import SlamConfig
from semmap.poses.slam.features import FrameFeatures
from semmap.poses.slam.tracking import TrackResult
from semmap.poses.slam.world_map import Keyframe, SlamMap
from semmap.types import transform_points


def need_keyframe(cfg: SlamConfig, feats: FrameFeatures, res: TrackResult, frames_since: int,
                  reference_inliers: int) -> bool:
    """Whether the frame just tracked should become a keyframe (tracking weakens, or new close structure)."""
    if frames_since < cfg.keyframe_min_frames:
        return False
    if frames_since >= cfg.keyframe_max_frames:
        return True
    close = feats.has_depth & (feats.depth < cfg.close_depth)
    tracked_close = int(close[res.kp].sum())
    untracked_close = int(close.sum()) - tracked_close
    new_structure = tracked_close < cfg.keyframe_close_points and untracked_close > cfg.keyframe_new_close_points
    weak = res.n_inliers < cfg.keyframe_tracked_ratio * reference_inliers
    return weak or new_structure


def create_keyframe(smap: SlamMap, cfg: SlamConfig, feats: FrameFeatures, T_wc: np.ndarray, frame: int,
                    kp: np.ndarray, lm: np.ndarray) -> Keyframe:
    """Add a keyframe with pose ``T_wc`` observing landmarks ``lm`` at keypoints ``kp``; every other keypoint
    with depth becomes a new landmark."""
    kf_id = len(smap.keyframes)
    per_kp = np.full(len(feats), -1, np.int64)
    per_kp[kp] = lm
    new = feats.has_depth & (per_kp < 0)
    ids = smap.landmarks.add(transform_points(T_wc, feats.xyz[new]), feats.desc[new], kf_id)
    per_kp[new] = ids
    kf = Keyframe(kf_id, frame, T_wc.copy(), feats, per_kp, feats.desc[feats.strongest(cfg.retrieval_features)])
    smap.add_keyframe(kf)
    return kf


def cull_landmarks(smap: SlamMap, cfg: SlamConfig, newest_kf: int) -> int:
    """Retire landmarks created at least two keyframes ago that were found in too few of the frames that should
    have seen them; returns how many."""
    lms = smap.landmarks
    found, visible = lms.col("found"), lms.col("visible")
    old = lms.col("first_kf") <= newest_kf - 2
    bad = lms.alive & old & (found < cfg.landmark_min_found_ratio * visible)
    lms.alive[bad] = False
    return int(bad.sum())
