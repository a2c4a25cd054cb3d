"""Relocalisation after tracking loss: rank keyframes by descriptor similarity, match the lost frame against the
best keyframes' landmarks, PnP + RANSAC without a pose prior, then confirm by tracking their local map."""

from __future__ import annotations

import numpy as np

from semmap.poses.slam.config import SlamConfig
from semmap.poses.slam.features import FrameFeatures
from semmap.poses.slam.matching import count_brute_force, match_brute_force
from semmap.poses.slam.pose_solver import pnp_ransac, refine_pose
from semmap.poses.slam.tracking import LocalMapTracker, TrackResult
from semmap.poses.slam.world_map import SlamMap


def rank_keyframes(smap: SlamMap, desc: np.ndarray, candidates: np.ndarray, n: int) -> np.ndarray:
    """The ``n`` keyframes among ``candidates`` whose retrieval descriptors best match ``desc``, best first,
    with their scores (ratio-test match counts)."""
    if len(candidates) == 0:
        return np.zeros((0, 2), np.int64)
    scores = np.array([count_brute_force(desc, smap.keyframes[int(k)].retrieval) for k in candidates])
    order = np.argsort(-scores, kind="stable")[:n]
    return np.column_stack([candidates[order], scores[order]])


def register_to_keyframes(smap: SlamMap, tracker: LocalMapTracker, feats: FrameFeatures, kf_ids: np.ndarray,
                          cfg: SlamConfig, min_inliers: int, seed: int = 0) -> TrackResult | None:
    """Pose of ``feats`` in the map from the landmarks of ``kf_ids`` (brute-force matching, PnP + RANSAC, then
    guided tracking of those keyframes' local map), or None when fewer than ``min_inliers`` agree."""
    lm_ids = smap.landmarks_of(kf_ids)
    if len(lm_ids) < min_inliers or len(feats) < min_inliers:
        return None
    q, t = match_brute_force(feats.desc, smap.landmarks.desc[lm_ids], max_dist=cfg.max_descriptor_distance,
                             ratio=0.85)
    if len(q) < min_inliers:
        return None
    lm = lm_ids[t]
    found = pnp_ransac(smap.landmarks.pos[lm], feats.uv[q], tracker.cam, None, cfg.ransac_reprojection_error,
                       max(cfg.ransac_iterations, 300), seed=seed)
    if found is None or found[1].sum() < min_inliers:
        return None
    T, inl = found
    T, ok = refine_pose(T, smap.landmarks.pos[lm[inl]], feats.uv[q[inl]], feats.ur[q[inl]],
                        tracker.inv_sigma2[feats.octave[q[inl]]], tracker.cam, tracker.disp_sigma)
    if ok.sum() < min_inliers:
        return None
    local = np.concatenate([kf_ids, *[smap.covisible(int(k), cfg.covisible_keyframes) for k in kf_ids]])
    res = tracker.track(feats, T, radius_scale=0.5, lm_ids=smap.landmarks_of(np.unique(local)))
    if res is None or res.n_inliers < min_inliers:
        return None
    return res


def relocalise(smap: SlamMap, tracker: LocalMapTracker, feats: FrameFeatures, cfg: SlamConfig,
               seed: int = 0) -> tuple[TrackResult, int] | None:
    """Pose of a frame after tracking loss and the keyframe it was registered to, or None."""
    if not smap.keyframes or len(feats) < cfg.reloc_min_inliers:
        return None
    query = feats.desc[feats.strongest(cfg.retrieval_features)]
    ranked = rank_keyframes(smap, query, np.arange(len(smap.keyframes)), cfg.loop_candidates)
    for kf_id, score in ranked:
        if score < cfg.reloc_min_inliers // 2:
            break
        res = register_to_keyframes(smap, tracker, feats, np.array([kf_id]), cfg, cfg.reloc_min_inliers, seed)
        if res is not None:
            return res, int(kf_id)
    return None
