"""gtsam back end: windowed bundle adjustment of keyframes and landmarks (virtual-stereo factors, Huber),
and pose-graph optimisation of all keyframes after a loop closure."""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np
from gtsam.symbol_shorthand import L, X

from semmap.poses.slam.pose_solver import CHI2_MONO, CHI2_STEREO, PinholeModel
from semmap.poses.slam.world_map import SlamMap
from semmap.types import invert_pose, snap_rigid, transform_points


def _huber(base: gtsam.noiseModel.Base, chi2: float) -> gtsam.noiseModel.Base:
    return gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(float(np.sqrt(chi2))), base)


def stereo_covariance(sigma_px: float, disp_sigma: float) -> np.ndarray:
    """Covariance of a virtual stereo measurement (uL, uR, v) with uR = uL - disparity: pixel noise
    ``sigma_px`` on uL and v, independent disparity noise ``disp_sigma`` (from the depth)."""
    s2, d2 = sigma_px**2, disp_sigma**2
    return np.array([[s2, s2, 0.0], [s2, s2 + d2, 0.0], [0.0, 0.0, s2]])


@dataclass
class BundleAdjuster:
    """Local bundle adjustment around the newest keyframe (the rest of the map stays fixed)."""

    cam: PinholeModel
    sigma: np.ndarray  # pixel standard deviation per pyramid level
    disp_sigma: float  # pixels, standard deviation of the virtual stereo disparity
    window: int = 6
    iterations: int = 5
    max_fixed: int = 10
    #: (radians, metres) standard deviations of the dense relative-pose factors of anchored keyframes
    anchor_sigma: tuple[float, float] | None = None

    def __post_init__(self) -> None:
        c = self.cam
        self._K = gtsam.Cal3_S2(c.fx, c.fy, 0.0, c.cx, c.cy)
        self._Ks = gtsam.Cal3_S2Stereo(c.fx, c.fy, 0.0, c.cx, c.cy, c.bf / c.fx)
        self._mono = [_huber(gtsam.noiseModel.Isotropic.Sigma(2, float(s)), CHI2_MONO) for s in self.sigma]
        self._stereo_for = -1.0
        self.set_disparity_noise(self.disp_sigma)
        self._fixed = gtsam.noiseModel.Isotropic.Sigma(6, 1e-5)  # a tight prior: much faster than an equality
        if self.anchor_sigma is not None:
            rot, trans = self.anchor_sigma
            self._anchor_noise = gtsam.noiseModel.Diagonal.Sigmas(np.array([rot] * 3 + [trans] * 3))

    def set_disparity_noise(self, disp_sigma: float) -> None:
        """Use ``disp_sigma`` (pixels) for the depth part of the stereo factors (models rebuilt on a 5% change)."""
        self.disp_sigma = float(disp_sigma)
        if abs(self.disp_sigma - self._stereo_for) > 0.05 * abs(self._stereo_for):
            self._stereo = [_huber(gtsam.noiseModel.Gaussian.Covariance(stereo_covariance(s, self.disp_sigma)),
                                   CHI2_STEREO) for s in self.sigma]
            self._stereo_for = self.disp_sigma

    def run(self, smap: SlamMap, kf_id: int) -> int:
        """Optimise ``kf_id``, its covisible keyframes and their landmarks; drop outlier observations.

        Returns the number of observations dropped.
        """
        window = np.concatenate([[kf_id], smap.covisible(kf_id, self.window - 1)]).astype(np.int64)
        lm_ids = smap.landmarks_of(window)
        rows = smap.live_obs()
        obs_lm = smap.obs.col("lm")[rows]
        rows = rows[np.isin(obs_lm, lm_ids)]
        # landmarks seen by one keyframe only say nothing about the poses: leave them out (much smaller problem)
        ids, counts = np.unique(smap.obs.col("lm")[rows], return_counts=True)
        lm_ids = ids[counts >= 2]
        rows = rows[np.isin(smap.obs.col("lm")[rows], lm_ids)]
        if len(lm_ids) == 0 or len(rows) == 0:
            return 0
        okf = smap.obs.col("kf")[rows]
        # keyframes outside the window that see these landmarks are fixed (the strongest few)
        others = okf[~np.isin(okf, window)]
        fixed = np.zeros(0, np.int64)
        if len(others):
            ids, counts = np.unique(others, return_counts=True)
            fixed = ids[np.argsort(-counts, kind="stable")[: self.max_fixed]]
        if len(fixed) == 0 or 0 in window:
            # hold the gauge: the oldest keyframe of the window stays put
            oldest = int(window.min())
            fixed = np.union1d(fixed, [oldest])
            window = window[window != oldest]
            if len(window) == 0:
                return 0
        keep = np.isin(okf, window) | np.isin(okf, fixed)
        return self._solve(smap, window, fixed, lm_ids, rows[keep], self.iterations)

    def _add_anchors(self, smap: SlamMap, graph: gtsam.NonlinearFactorGraph, window: np.ndarray,
                     fixed: np.ndarray) -> None:
        """Relative-pose factors of keyframes in ``window`` whose dense anchor keyframe is in the problem too."""
        if self.anchor_sigma is None:
            return
        present = set(np.concatenate([window, fixed]).astype(int).tolist())
        for k in window:
            anchor = smap.keyframes[int(k)].anchor
            if anchor is not None and int(anchor[0]) in present:
                graph.add(gtsam.BetweenFactorPose3(X(int(anchor[0])), X(int(k)), gtsam.Pose3(anchor[1]),
                                                   self._anchor_noise))

    def run_global(self, smap: SlamMap, iterations: int = 10) -> int:
        """Optimise every keyframe (the first one fixed) and every landmark seen by two or more keyframes."""
        if len(smap.keyframes) < 2:
            return 0
        rows = smap.live_obs()
        ids, counts = np.unique(smap.obs.col("lm")[rows], return_counts=True)
        lm_ids = ids[counts >= 2]
        rows = rows[np.isin(smap.obs.col("lm")[rows], lm_ids)]
        if len(lm_ids) == 0:
            return 0
        window = np.arange(1, len(smap.keyframes))
        return self._solve(smap, window, np.array([0]), lm_ids, rows, iterations)

    def _solve(self, smap: SlamMap, window: np.ndarray, fixed: np.ndarray, lm_ids: np.ndarray, rows: np.ndarray,
               iterations: int) -> int:
        """Bundle adjustment of keyframes ``window`` and landmarks ``lm_ids`` over observation ``rows``
        (keyframes ``fixed`` held in place); writes the result back and drops outlier observations."""
        okf, okp, olm = smap.obs.col("kf")[rows], smap.obs.col("kp")[rows], smap.obs.col("lm")[rows]
        graph = gtsam.NonlinearFactorGraph()
        values = gtsam.Values()
        for k in np.concatenate([window, fixed]):
            kf = smap.keyframes[int(k)]
            values.insert(X(int(k)), gtsam.Pose3(kf.T_wc))
        for k in fixed:
            graph.add(gtsam.PriorFactorPose3(X(int(k)), gtsam.Pose3(smap.keyframes[int(k)].T_wc), self._fixed))
        self._add_anchors(smap, graph, window, fixed)
        pos = smap.landmarks.pos
        for lm in lm_ids:
            values.insert(L(int(lm)), gtsam.Point3(*pos[lm]))
        # per observation: measurement from its keyframe's keypoint
        uv = np.empty((len(rows), 2))
        ur = np.empty(len(rows))
        octv = np.empty(len(rows), np.int64)
        for k in np.unique(okf):
            sel = okf == k
            f = smap.keyframes[int(k)].feats
            uv[sel], ur[sel], octv[sel] = f.uv[okp[sel]], f.ur[okp[sel]], f.octave[okp[sel]]
        stereo = np.isfinite(ur)
        octv = np.minimum(octv, len(self.sigma) - 1)
        for i in range(len(rows)):
            if stereo[i]:
                graph.add(gtsam.GenericStereoFactor3D(gtsam.StereoPoint2(uv[i, 0], ur[i], uv[i, 1]),
                                                      self._stereo[octv[i]], X(int(okf[i])), L(int(olm[i])),
                                                      self._Ks))
            else:
                graph.add(gtsam.GenericProjectionFactorCal3_S2(uv[i], self._mono[octv[i]], X(int(okf[i])),
                                                               L(int(olm[i])), self._K))
        # landmarks seen once with no depth would be unconstrained along the ray: anchor them weakly
        seen = np.bincount(np.searchsorted(lm_ids, olm[stereo]), minlength=len(lm_ids))
        weak = gtsam.noiseModel.Isotropic.Sigma(3, 0.5)
        for j in np.flatnonzero(seen == 0):
            graph.add(gtsam.PriorFactorPoint3(L(int(lm_ids[j])), gtsam.Point3(*pos[lm_ids[j]]), weak))
        params = gtsam.LevenbergMarquardtParams()
        params.setMaxIterations(int(iterations))
        params.setLinearSolverType("SEQUENTIAL_CHOLESKY")
        try:
            result = gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()
        except RuntimeError:
            return 0
        for k in window:
            smap.keyframes[int(k)].T_wc = result.atPose3(X(int(k))).matrix()
        new_pos = np.array([result.atPoint3(L(int(lm))) for lm in lm_ids]).reshape(-1, 3)
        pos[lm_ids] = new_pos
        # outliers: chi-square of each observation under the optimised estimate
        T_cw = {int(k): invert_pose(smap.keyframes[int(k)].T_wc) for k in np.unique(okf)}
        pc = np.empty((len(rows), 3))
        for k, T in T_cw.items():
            sel = okf == k
            pc[sel] = transform_points(T, pos[olm[sel]])
        z = np.where(pc[:, 2] > 1e-3, pc[:, 2], 1e-3)
        puv, _ = self.cam.project(np.column_stack([pc[:, :2], z]))
        disp_err = np.where(stereo, uv[:, 0] - np.nan_to_num(ur) - self.cam.bf / z, 0.0)
        chi2 = ((uv - puv) ** 2).sum(1) / self.sigma[octv] ** 2 + disp_err**2 / self.disp_sigma**2
        bad = (pc[:, 2] <= 1e-3) | (chi2 > np.where(stereo, CHI2_STEREO, CHI2_MONO))
        if bad.any():
            smap.drop_observations(rows[bad])
        return int(bad.sum())


def optimise_pose_graph(poses: np.ndarray, edges: list[tuple[int, int, np.ndarray, float]],
                        fixed: int = 0, iterations: int = 30,
                        sigmas: tuple[float, float] = (0.01, 0.02)) -> np.ndarray:
    """Keyframe poses ``T_world_cam`` that best agree with relative-pose ``edges`` ``(i, j, T_i_j, weight)``,
    keyframe ``fixed`` held in place (gtsam Levenberg-Marquardt). An edge of weight w has standard deviations
    ``sigmas`` (radians, metres) divided by sqrt(w)."""
    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    for i, T in enumerate(poses):
        values.insert(X(i), gtsam.Pose3(snap_rigid(T)))
    graph.add(gtsam.PriorFactorPose3(X(fixed), gtsam.Pose3(poses[fixed]), gtsam.noiseModel.Isotropic.Sigma(6, 1e-6)))
    for i, j, T_ij, weight in edges:
        sd = np.repeat(np.asarray(sigmas, np.float64), 3) / np.sqrt(max(weight, 1e-6))
        graph.add(gtsam.BetweenFactorPose3(X(i), X(j), gtsam.Pose3(snap_rigid(T_ij)),
                                           gtsam.noiseModel.Diagonal.Sigmas(sd)))
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(iterations)
    result = gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()
    return np.array([result.atPose3(X(i)).matrix() for i in range(len(poses))])
