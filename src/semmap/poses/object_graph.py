"""The keyframe pose graph with object edges (the object-oriented SLAM paper's Sec. 3.4, eqs. 19-20), as plain math.

Eq. 20 is solved in closed form (:func:`fit_rigid`); :func:`optimise_with_object_edges` ties consecutive keyframes by
a tracker's relative poses and adds object edges with a Huber kernel (gtsam Levenberg-Marquardt);
:func:`apply_corrections` moves every frame with the correction of the keyframes around it. The orchestration
(instances, tracking, object association) is in :mod:`semmap.object_slam`.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import gtsam
import numpy as np
from gtsam.symbol_shorthand import X

from semmap.types import Trajectory, interpolate_pose, invert_pose, rotation_angle, snap_rigid

log = logging.getLogger("semmap")

#: 0.95 quantile of chi-square with 6 degrees of freedom: an object edge within it agrees with the tracker.
CHI2_6DOF_95 = 12.59
#: 0.999 quantile: an object edge beyond it, against the tracker's drift over the steps between its keyframes plus
#: its own noise, is a wrong registration or association, not drift.
CHI2_6DOF_999 = 22.46


@dataclass(frozen=True)
class ObjectEdge:
    """A relative pose ``T_a_b`` between keyframes a and b measured from object centroids, with standard
    deviations (3 rotation in radians, 3 translation in metres)."""

    a: int
    b: int
    T_a_b: np.ndarray
    sigmas: np.ndarray


def fit_rigid(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """``T`` minimising ``sum |p_i - T q_i|^2`` (eq. 20) in closed form (Umeyama / Kabsch, no scale)."""
    mp, mq = p.mean(axis=0), q.mean(axis=0)
    H = (q - mq).T @ (p - mp)
    U, _, Vt = np.linalg.svd(H)
    D = np.diag([1.0, 1.0, np.sign(np.linalg.det(Vt.T @ U.T))])
    R = Vt.T @ D @ U.T
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = mp - R @ mq
    return T


def agrees(T_ab_tracker: np.ndarray, T_ab_objects: np.ndarray, sigmas: np.ndarray) -> bool:
    """Whether the tracker's relative pose lies within the object edge's noise (chi-square, 6 dof, 95 %)."""
    diff = invert_pose(T_ab_objects) @ T_ab_tracker
    angle = rotation_angle(diff)
    d2 = (angle / sigmas[0]) ** 2 + float((diff[:3, 3] ** 2).sum()) / sigmas[3] ** 2
    return d2 < CHI2_6DOF_95


def plausible(T_ab_tracker: np.ndarray, T_ab_objects: np.ndarray, sigmas: np.ndarray, steps: int,
              odometry_sigma: tuple[float, float]) -> bool:
    """Whether the tracker can have drifted from the object edge over ``steps`` keyframe steps of standard
    deviations ``odometry_sigma`` (radians, metres; added in quadrature with the edge's own): chi-square, 6 dof,
    99.9 %."""
    diff = invert_pose(T_ab_objects) @ T_ab_tracker
    var_r = steps * odometry_sigma[0] ** 2 + sigmas[0] ** 2
    var_t = steps * odometry_sigma[1] ** 2 + sigmas[3] ** 2
    d2 = rotation_angle(diff) ** 2 / var_r + float((diff[:3, 3] ** 2).sum()) / var_t
    return d2 < CHI2_6DOF_999



def optimise_with_object_edges(T_kf: np.ndarray, edges: list[ObjectEdge], *, odometry_sigma: tuple[float, float],
                               huber: float = 1.345, iterations: int = 50) -> np.ndarray:
    """Keyframe poses ``T_world_cam`` (K, 4, 4) after the pose graph: the first held, consecutive keyframes tied
    by their relative poses in ``T_kf`` (standard deviations ``odometry_sigma``: radians, metres), plus the object
    edges under a Huber kernel of width ``huber`` standard deviations."""
    graph = gtsam.NonlinearFactorGraph()
    values = gtsam.Values()
    for i, T in enumerate(T_kf):
        values.insert(X(i), gtsam.Pose3(snap_rigid(T)))
    graph.add(gtsam.PriorFactorPose3(X(0), gtsam.Pose3(snap_rigid(T_kf[0])), gtsam.noiseModel.Isotropic.Sigma(6, 1e-6)))
    odo = gtsam.noiseModel.Diagonal.Sigmas(np.repeat(np.asarray(odometry_sigma, float), 3))
    for i in range(len(T_kf) - 1):
        step = gtsam.Pose3(snap_rigid(invert_pose(T_kf[i]) @ T_kf[i + 1]))
        graph.add(gtsam.BetweenFactorPose3(X(i), X(i + 1), step, odo))
    kernel = gtsam.noiseModel.mEstimator.Huber.Create(huber)
    for e in edges:
        noise = gtsam.noiseModel.Robust.Create(kernel, gtsam.noiseModel.Diagonal.Sigmas(np.asarray(e.sigmas, float)))
        graph.add(gtsam.BetweenFactorPose3(X(e.a), X(e.b), gtsam.Pose3(snap_rigid(e.T_a_b)), noise))
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(iterations)
    try:
        result = gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()
    except RuntimeError as exc:
        log.warning("object pose graph did not solve (%s); poses left as the tracker gave them", exc)
        return np.asarray(T_kf)
    return np.array([result.atPose3(X(i)).matrix() for i in range(len(T_kf))])


def apply_corrections(base: Trajectory, kf_names: list[str], before: np.ndarray, after: np.ndarray) -> Trajectory:
    """Move every frame with the correction of its keyframes: ``C_k = after_k before_k^-1`` at keyframes,
    interpolated between consecutive keyframes by frame position (held before the first and after the last)."""
    position = {n: i for i, n in enumerate(base.names)}
    kf_pos = np.array([position[n] for n in kf_names])
    corr = np.array([a @ invert_pose(b) for a, b in zip(after, before, strict=True)])
    poses = base.poses.copy()
    for i in range(len(base)):
        j = int(np.searchsorted(kf_pos, i, side="right")) - 1
        if j < 0:
            C = corr[0]
        elif j >= len(kf_pos) - 1:
            C = corr[-1]
        else:
            alpha = (i - kf_pos[j]) / (kf_pos[j + 1] - kf_pos[j])
            C = interpolate_pose(corr[j], corr[j + 1], alpha)
        poses[i] = snap_rigid(C @ base.poses[i])
    return Trajectory(base.timestamps, poses, base.names)
