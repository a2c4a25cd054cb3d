"""Loop closure: find older keyframes that look like the newest one (descriptor retrieval with a covisibility-based
score check), verify geometrically (PnP + RANSAC inliers), then optimise the keyframe pose graph (gtsam) and
carry the correction over to the landmarks."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from semmap.poses.slam.config import SlamConfig
from semmap.poses.slam.matching import count_brute_force
from semmap.poses.slam.optimisation import optimise_pose_graph
from semmap.poses.slam.relocalisation import rank_keyframes, register_to_keyframes
from semmap.poses.slam.tracking import LocalMapTracker, TrackResult
from semmap.poses.slam.world_map import Keyframe, SlamMap
from semmap.types import invert_pose, rotation_angle

#: keyframes sharing at least this many landmarks are tied by a pose-graph edge
COVISIBILITY_EDGE_MIN = 100
#: loops that would move the keyframe less than this only link the maps (no pose-graph correction)
MIN_CORRECTION_M = 0.02
MIN_CORRECTION_DEG = 1.0
#: keyframes after a closed loop during which no new loop is searched
COOLDOWN_KEYFRAMES = 5


@dataclass
class LoopCloser:
    """Detects and closes loops at keyframes; remembers every loop edge for later pose-graph optimisations."""

    smap: SlamMap
    tracker: LocalMapTracker
    cfg: SlamConfig
    loop_edges: list[tuple[int, int, np.ndarray]] = field(default_factory=list)
    last_loop_kf: int = -(10**9)

    def detect(self, kf: Keyframe) -> tuple[int, TrackResult] | None:
        """An older keyframe that ``kf`` revisits and ``kf``'s pose relative to that part of the map, or None."""
        cfg, smap = self.cfg, self.smap
        if kf.id - self.last_loop_kf < COOLDOWN_KEYFRAMES or kf.id < cfg.loop_min_keyframe_gap:
            return None
        neighbours = smap.covisible(kf.id, 30)
        old = np.arange(kf.id - cfg.loop_min_keyframe_gap + 1)
        old = old[~np.isin(old, neighbours)]
        if len(old) == 0:
            return None
        # a candidate must look at least as similar as the keyframe's own close neighbours
        near = neighbours[:3]
        floor = min((count_brute_force(kf.retrieval, smap.keyframes[int(k)].retrieval) for k in near), default=0)
        ranked = rank_keyframes(smap, kf.retrieval, old, cfg.loop_candidates)
        for cand, score in ranked:
            if score < max(floor * 0.5, 0.1 * cfg.retrieval_features):
                break
            group = np.concatenate([[cand], smap.covisible(int(cand), 5)])
            group = group[group <= kf.id - cfg.loop_min_keyframe_gap]
            res = register_to_keyframes(smap, self.tracker, kf.feats, group, cfg, cfg.loop_min_inliers,
                                        seed=kf.id)
            if res is not None:
                return int(cand), res
        return None

    def close(self, kf: Keyframe, loop_kf: int, res: TrackResult) -> np.ndarray:
        """Correct the map for the loop ``kf`` -> ``loop_kf`` (``res``: ``kf``'s pose in the old map and its matches);
        returns the (K, 4, 4) per-keyframe corrections ``T_new @ T_old^-1``."""
        smap = self.smap
        old_poses = smap.kf_poses()
        T_wc_loop = invert_pose(res.T_cw)
        T_ij = invert_pose(old_poses[loop_kf]) @ T_wc_loop
        self.loop_edges.append((loop_kf, kf.id, T_ij))
        self.last_loop_kf = kf.id
        jump = invert_pose(kf.T_wc) @ T_wc_loop
        if np.linalg.norm(jump[:3, 3]) < MIN_CORRECTION_M and rotation_angle(jump) < np.radians(MIN_CORRECTION_DEG):
            # drift below what one PnP can measure: link the maps, leave the poses alone
            self._fuse(kf, res)
            return np.repeat(np.eye(4)[None], len(old_poses), 0)
        try:
            new_poses = optimise_pose_graph(old_poses, self._edges(old_poses), fixed=0)
        except RuntimeError:  # an indeterminate graph: keep the map as it is rather than stop tracking
            self.loop_edges.pop()
            return np.repeat(np.eye(4)[None], len(old_poses), 0)
        corrections = new_poses @ invert_pose(old_poses)
        for k, T in zip(smap.keyframes, new_poses, strict=True):
            k.T_wc = T
        lms = smap.landmarks
        n = lms.n
        ref = lms.col("ref_kf")[:n]
        C = corrections[np.maximum(ref, 0)]
        pos = lms.pos
        pos[:] = np.einsum("nij,nj->ni", C[:, :3, :3], pos) + C[:, :3, 3]
        self._fuse(kf, res)
        self.last_loop_kf = kf.id
        return corrections

    def _edges(self, poses: np.ndarray) -> list[tuple[int, int, np.ndarray, float]]:
        """Pose-graph edges: consecutive keyframes, strongly covisible keyframes and every loop."""
        smap = self.smap
        K = len(poses)
        edges = [(i, i + 1, invert_pose(poses[i]) @ poses[i + 1], 1.0) for i in range(K - 1)]
        rows = smap.live_obs()
        kf, lm = smap.obs.col("kf")[rows], smap.obs.col("lm")[rows]
        M = sp.csr_matrix((np.ones(len(rows)), (kf, lm)), shape=(K, smap.landmarks.n))
        C = sp.triu(M @ M.T, k=2).tocoo()
        strong = C.data >= COVISIBILITY_EDGE_MIN
        edges += [(int(i), int(j), invert_pose(poses[i]) @ poses[j], 1.0)
                  for i, j in zip(C.row[strong], C.col[strong], strict=True)]
        edges += [(i, j, T, 1.0) for i, j, T in self.loop_edges]
        return edges

    def _fuse(self, kf: Keyframe, res: TrackResult) -> None:
        """Let ``kf`` observe the old landmarks it matched; its own duplicates of them are retired."""
        smap = self.smap
        dup = kf.lm[res.kp]
        fresh = (dup >= 0) & (smap.landmarks.col("first_kf")[np.maximum(dup, 0)] == kf.id)
        smap.landmarks.alive[dup[fresh]] = False
        rows = np.flatnonzero((smap.obs.col("kf") == kf.id) & smap.obs.col("valid"))
        smap.obs.col("valid")[rows[np.isin(smap.obs.col("kp")[rows], res.kp)]] = False
        kf.lm[res.kp] = res.lm
        smap.obs.add(kf.id, res.kp, res.lm)
