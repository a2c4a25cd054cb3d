"""Camera trajectory accuracy with ``evo``: ATE after SE(3) Umeyama alignment, RPE per frame, and a plot.

Poses are associated by timestamp (evo's nearest-time sync within ``max_time_diff``); ground-truth rotations
are re-orthonormalised first (real ground truth is slightly off and evo rejects it).
"""

from __future__ import annotations

import copy
import io
import logging
from pathlib import Path

import numpy as np
from evo.core import metrics, sync
from evo.core.geometry import GeometryException
from evo.core.trajectory import PoseTrajectory3D

from semmap.errors import ConfigError
from semmap.files.atomic import write_bytes_atomic
from semmap.io.trajectory import clean_poses
from semmap.limits import LIMITS
from semmap.types import Trajectory, rotation_angle

log = logging.getLogger("semmap")

#: Fewest associated poses an evaluation accepts (Umeyama alignment needs three non-collinear positions).
MIN_MATCHES = 3
#: How a trajectory too degenerate for the Umeyama fit (a camera that stays put or moves along a line) is aligned.
FALLBACK_ALIGNMENT = "se3 offset of the first matched pose"


def _to_evo(trajectory: Trajectory, source: str) -> PoseTrajectory3D:
    """evo trajectory with cleaned (re-orthonormalised) rotations; :class:`ConfigError` when empty."""
    if len(trajectory) == 0:
        raise ConfigError(f"{source} trajectory has no poses")
    poses = clean_poses(trajectory.poses, f"{source} trajectory")
    far = float(np.abs(poses[:, :3, 3]).max())
    if far > LIMITS["position"].hi:
        raise ConfigError(f"{source} trajectory has a camera {far:.3g} m from the origin (more than "
                          f"{LIMITS['position'].hi:g} m): not a trajectory in metres")
    return PoseTrajectory3D(poses_se3=list(poses), timestamps=trajectory.timestamps.copy(), name=source)


def synchronize(gt: Trajectory, est: Trajectory, max_time_diff: float = 0.02
                ) -> tuple[PoseTrajectory3D, PoseTrajectory3D]:
    """(ground truth, estimate) evo trajectories reduced to the poses matched by timestamp.

    :class:`ConfigError` when fewer than :data:`MIN_MATCHES` poses match.
    """
    ref, est_evo = _to_evo(gt, "ground-truth"), _to_evo(est, "estimated")
    try:
        ref_s, est_s = sync.associate_trajectories(ref, est_evo, max_diff=max_time_diff)
        matched = ref_s.num_poses
    except sync.SyncException:
        matched = 0
    if matched < MIN_MATCHES:
        raise ConfigError(
            f"only {matched} estimated poses match a ground-truth pose within {max_time_diff} s (need at least "
            f"{MIN_MATCHES}); ground truth spans t=[{gt.timestamps[0]:.3f}, {gt.timestamps[-1]:.3f}] s "
            f"({len(gt)} poses), the estimate t=[{est.timestamps[0]:.3f}, {est.timestamps[-1]:.3f}] s "
            f"({len(est)} poses)")
    return ref_s, est_s


def align(ref: PoseTrajectory3D, est: PoseTrajectory3D, *, with_scale: bool = False
          ) -> tuple[PoseTrajectory3D, np.ndarray]:
    """Copy of ``est`` moved onto ``ref`` by the SE(3) Umeyama fit of its positions (Sim(3) ``with_scale``: the
    fit's 4x4 then has the scale in its rotation block), and the fit."""
    aligned = copy.deepcopy(est)
    try:
        R, t, scale = aligned.align(ref, correct_scale=with_scale)
    except GeometryException as exc:
        raise ConfigError(f"cannot align the estimated trajectory to the ground truth: {exc} "
                          f"(does the camera move?)") from None
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = (scale if with_scale else 1.0) * R, t
    return aligned, T


def alignment_to_ground_truth(gt: Trajectory, est: Trajectory, *, max_time_diff: float = 0.02
                              ) -> tuple[np.ndarray, dict]:
    """``T_gt_est`` (4x4) taking ``est``'s frame onto the ground truth's, and how it was found: the SE(3) Umeyama fit
    over the poses matched by timestamp (the alignment of :func:`evaluate_trajectory`'s ATE), or, where the positions
    are too degenerate for it (a camera that stays put or moves along a line), the first matched pose's offset.

    :class:`ConfigError` when fewer than :data:`MIN_MATCHES` poses match."""
    ref, est_s = synchronize(gt, est, max_time_diff)
    _, T, why = align_or_offset(ref, est_s)
    if why is not None:
        return T, {"method": FALLBACK_ALIGNMENT, "frames": 1, "why": why}
    return T, {"method": "se3 umeyama on the trajectory", "frames": int(ref.num_poses)}


def align_or_offset(ref: PoseTrajectory3D, est: PoseTrajectory3D) -> tuple[PoseTrajectory3D, np.ndarray, str | None]:
    """:func:`align` (SE(3)), or where the positions are too degenerate for the fit, ``est`` moved so that its first
    pose lies on ``ref``'s; with why the fit was not possible (None when it was)."""
    try:
        return (*align(ref, est), None)
    except ConfigError as exc:
        T = ref.poses_se3[0] @ np.linalg.inv(est.poses_se3[0])
        T[3] = (0.0, 0.0, 0.0, 1.0)
        moved = copy.deepcopy(est)
        moved.transform(T)
        return moved, T, str(exc)


def _ape(ref: PoseTrajectory3D, est: PoseTrajectory3D) -> metrics.APE:
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((ref, est))
    return ape


def _rpe(ref: PoseTrajectory3D, est: PoseTrajectory3D, relation: metrics.PoseRelation) -> metrics.RPE:
    rpe = metrics.RPE(relation, delta=1, delta_unit=metrics.Unit.frames, all_pairs=False)
    rpe.process_data((ref, est))
    return rpe


def evaluate_trajectory(gt: Trajectory, est: Trajectory, *, max_time_diff: float = 0.02) -> dict:
    """ATE (after SE(3) alignment, metres: rmse/mean/median/max) and RPE over one frame (rmse/mean, metres and
    degrees, also per second of motion) of ``est`` against ``gt``, with the number of matched poses.

    ``sim3_scale`` and ``ate_sim3_rmse_m`` come from a Sim(3) fit instead: an RGB-D tracker's trajectory has the
    metric scale of its depth, so a scale away from 1 says the depth calibration and the ground truth disagree.
    """
    ref, est_s = synchronize(gt, est, max_time_diff)
    aligned, T_align, why = align_or_offset(ref, est_s)
    if why is None:
        scaled, T_sim3 = align(ref, est_s, with_scale=True)
        method = {"alignment_method": "se3 umeyama on the trajectory"}
    else:  # a scoring step warns and goes on: no fit, no scale, the ATE after the first pose's offset
        log.warning("%s; the ATE is taken after the %s instead, and no Sim(3) scale is given", why,
                    FALLBACK_ALIGNMENT)
        scaled = T_sim3 = None
        method = {"alignment_method": FALLBACK_ALIGNMENT, "alignment_not_possible": why}
    ate = _ape(ref, aligned)
    rpe_t = _rpe(ref, est_s, metrics.PoseRelation.translation_part)
    rpe_r = _rpe(ref, est_s, metrics.PoseRelation.rotation_angle_deg)
    dt = float(np.median(np.diff(ref.timestamps)))
    stat = metrics.StatisticsType
    return {
        "matched": int(ref.num_poses),
        "gt_poses": len(gt),
        "est_poses": len(est),
        "ate_rmse_m": float(ate.get_statistic(stat.rmse)),
        "ate_mean_m": float(ate.get_statistic(stat.mean)),
        "ate_median_m": float(ate.get_statistic(stat.median)),
        "ate_max_m": float(ate.get_statistic(stat.max)),
        "sim3_scale": None if T_sim3 is None else float(np.cbrt(np.linalg.det(T_sim3[:3, :3]))),
        "ate_sim3_rmse_m": None if scaled is None else float(_ape(ref, scaled).get_statistic(stat.rmse)),
        "rpe_trans_m": float(rpe_t.get_statistic(stat.rmse)),
        "rpe_trans_mean_m": float(rpe_t.get_statistic(stat.mean)),
        "rpe_rot_deg": float(rpe_r.get_statistic(stat.rmse)),
        "rpe_rot_mean_deg": float(rpe_r.get_statistic(stat.mean)),
        "rpe_trans_m_per_s": float(rpe_t.get_statistic(stat.rmse)) / dt if dt > 0 else float("nan"),
        "rpe_rot_deg_per_s": float(rpe_r.get_statistic(stat.rmse)) / dt if dt > 0 else float("nan"),
        "gt_path_length_m": float(ref.path_length),
        "alignment": T_align.round(9).tolist(),
        **method,
    }


def ate_without_alignment(gt: Trajectory, est: Trajectory, *, max_time_diff: float = 0.02) -> dict:
    """ATE (rmse/mean/median/max, metres) of ``est`` taken as it is, in the ground truth's frame."""
    ref, est_s = synchronize(gt, est, max_time_diff)
    ate = _ape(ref, est_s)
    stat = metrics.StatisticsType
    return {
        "matched": int(ref.num_poses),
        "ate_rmse_m": float(ate.get_statistic(stat.rmse)),
        "ate_mean_m": float(ate.get_statistic(stat.mean)),
        "ate_median_m": float(ate.get_statistic(stat.median)),
        "ate_max_m": float(ate.get_statistic(stat.max)),
    }


# --------------------------------------------------------------------------------------------------
# Several trajectories
# --------------------------------------------------------------------------------------------------
def on_common_frames(reference: Trajectory, estimates: dict[str, Trajectory], *, max_time_diff: float = 0.02
                     ) -> tuple[Trajectory, dict[str, Trajectory]]:
    """The reference's poses that every estimate matches within ``max_time_diff`` (nearest timestamp), and each
    estimate's matching poses in the same order: trajectories over the same frames, for frame-wise comparisons.

    :class:`ConfigError` when fewer than :data:`MIN_MATCHES` frames are common to all."""
    keep = np.ones(len(reference), bool)
    rows: dict[str, np.ndarray] = {}
    for name, est in estimates.items():
        if len(est) == 0:
            raise ConfigError(f"{name} trajectory has no poses")
        order = np.argsort(est.timestamps, kind="stable")
        stamps = est.timestamps[order]
        right = np.clip(np.searchsorted(stamps, reference.timestamps), 1, max(len(stamps) - 1, 1))
        left = right - 1
        pick = np.where(np.abs(stamps[left] - reference.timestamps) <= np.abs(stamps[right] - reference.timestamps),
                        left, right) if len(stamps) > 1 else np.zeros(len(reference), int)
        keep &= np.abs(stamps[pick] - reference.timestamps) <= max_time_diff
        rows[name] = order[pick]
    if keep.sum() < MIN_MATCHES:
        raise ConfigError(f"only {int(keep.sum())} reference poses are matched by every trajectory within "
                          f"{max_time_diff} s (need at least {MIN_MATCHES})")
    names = tuple(n for n, k in zip(reference.names, keep, strict=True) if k) if reference.names else ()
    ref = Trajectory(reference.timestamps[keep], reference.poses[keep], names)
    out = {name: Trajectory(ref.timestamps, estimates[name].poses[r[keep]], names) for name, r in rows.items()}
    return ref, out


def rotation_disagreement_deg(a: Trajectory, b: Trajectory, frames: int) -> float:
    """RMS angle (degrees) between two trajectories' relative rotations over ``frames`` frames, from every start
    frame; both hold the same frames in order. Rotation angles need no alignment and no scale, and a fixed rotation
    between the two cameras changes them only to second order."""
    if not 0 < frames < len(a):
        raise ConfigError(f"--rotation-frames {frames}: relative rotations over {frames} frames need more than "
                          f"{frames} common frames (have {len(a)})")
    ra, rb = a.poses[:, :3, :3], b.poses[:, :3, :3]
    rel_a = np.transpose(ra[:-frames], (0, 2, 1)) @ ra[frames:]
    rel_b = np.transpose(rb[:-frames], (0, 2, 1)) @ rb[frames:]
    angles = [rotation_angle(x.T @ y) for x, y in zip(rel_a, rel_b, strict=True)]
    return float(np.degrees(np.sqrt(np.mean(np.square(angles)))))


#: Scores kept per trajectory when several are compared (the full set is printed for a single estimate).
SUMMARY_KEYS = ("matched", "ate_rmse_m", "ate_sim3_rmse_m", "sim3_scale", "rpe_trans_m", "rpe_rot_deg")


def compare_trajectories(reference: Trajectory, estimates: dict[str, Trajectory], *,
                         reference2: Trajectory | None = None, pairwise: bool = False,
                         rotation_frames: int | None = None, max_time_diff: float = 0.02) -> dict:
    """Several estimates against one reference, and optionally against each other and a second reference.

    - ``estimates``: each one's ATE / Sim(3) / RPE summary against ``reference``;
    - ``pairwise``: the ATE between every two estimates and the part of their errors they share: read each error
      over the frames as a common part plus its own; estimates with ATEs a and b lying d apart share
      sqrt((a² + b² - d²) / 2) (exact when their own parts are independent). Unrelated trackers that share most of
      their error point at an error of the reference, not of any tracker;
    - ``reference2``: every estimate and the first reference scored against a second, independent reference;
    - ``rotation_frames``: the RMS disagreement of relative rotations over that many frames between every two of
      the reference, the second reference and the estimates, on the frames all of them hold.
    """
    result: dict = {"estimates": {}}
    ates: dict[str, float] = {}
    for name, est in estimates.items():
        scores = evaluate_trajectory(reference, est, max_time_diff=max_time_diff)
        result["estimates"][name] = {k: scores[k] for k in SUMMARY_KEYS}
        ates[name] = scores["ate_rmse_m"]
    if pairwise:
        pairs = []
        names = list(estimates)
        for i, a in enumerate(names):
            for b in names[i + 1:]:
                apart = evaluate_trajectory(estimates[a], estimates[b], max_time_diff=max_time_diff)["ate_rmse_m"]
                shared = (ates[a] ** 2 + ates[b] ** 2 - apart ** 2) / 2
                corr = shared / (ates[a] * ates[b]) if ates[a] * ates[b] > 0 else float("nan")
                pairs.append({"between": [a, b], "ate_m": apart, "shared_m": float(np.sqrt(max(shared, 0.0))),
                              "correlation": float(corr)})
        result["pairwise"] = pairs
    if reference2 is not None:
        against = {"reference": reference, **estimates}
        result["reference2"] = {}
        for name, traj in against.items():
            scores = evaluate_trajectory(reference2, traj, max_time_diff=max_time_diff)
            result["reference2"][name] = {k: scores[k] for k in ("matched", "ate_rmse_m", "ate_sim3_rmse_m",
                                                                  "sim3_scale")}
    if rotation_frames is not None:
        others = dict(estimates)
        if reference2 is not None:
            others = {"reference2": reference2, **others}
        ref, common = on_common_frames(reference, others, max_time_diff=max_time_diff)
        everything = {"reference": ref, **common}
        labels = list(everything)
        matrix = [[rotation_disagreement_deg(everything[a], everything[b], rotation_frames) for b in labels]
                  for a in labels]
        result["rotation_disagreement_deg"] = {"frames": rotation_frames, "common_frames": len(ref),
                                               "order": labels, "matrix": matrix}
    return result


# --------------------------------------------------------------------------------------------------
# Plot
# --------------------------------------------------------------------------------------------------
def plot_trajectories(path: str | Path, gt: Trajectory, estimates: dict[str, Trajectory], *,
                      max_time_diff: float = 0.02, title: str = "") -> Path:
    """PNG with the aligned trajectories seen from above (the ground truth's two largest-extent axes) and each
    estimate's position error over time; written atomically."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    gt_clean = Trajectory(gt.timestamps, clean_poses(gt.poses, "ground-truth trajectory"), gt.names)
    extent = np.ptp(gt_clean.positions, axis=0)
    ax0, ax1 = sorted(np.argsort(extent)[-2:].tolist())
    axis_names = "xyz"

    fig = Figure(figsize=(13, 5.5), dpi=100)
    FigureCanvasAgg(fig)
    top, err = fig.add_subplot(1, 2, 1), fig.add_subplot(1, 2, 2)
    t0 = gt_clean.timestamps[0]
    top.plot(gt_clean.positions[:, ax0], gt_clean.positions[:, ax1], color="black", lw=2, label="ground truth")
    for name, est in estimates.items():
        ref, est_s = synchronize(gt_clean, est, max_time_diff)
        aligned, _, _ = align_or_offset(ref, est_s)
        xyz = aligned.positions_xyz
        errors = np.linalg.norm(xyz - ref.positions_xyz, axis=1)
        rmse = float(np.sqrt(np.mean(errors**2)))
        line, = top.plot(xyz[:, ax0], xyz[:, ax1], lw=1.2, label=f"{name} (ATE {100 * rmse:.2f} cm)")
        err.plot(ref.timestamps - t0, 100 * errors, lw=1.2, color=line.get_color(), label=name)
    top.set_xlabel(f"{axis_names[ax0]} (m)")
    top.set_ylabel(f"{axis_names[ax1]} (m)")
    top.set_aspect("equal", adjustable="datalim")
    top.set_title("trajectories (aligned, SE(3))")
    top.legend(fontsize=8)
    err.set_xlabel("time (s)")
    err.set_ylabel("position error (cm)")
    err.set_title("absolute trajectory error")
    err.grid(alpha=0.3)
    if estimates:
        err.legend(fontsize=8)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png")
    return write_bytes_atomic(path, buffer.getvalue())


def plot_position_errors(path: str | Path, reference: Trajectory, estimates: dict[str, Trajectory], *,
                         with_scale: bool = False, title: str = "", highlight: str | None = None) -> Path:
    """PNG of each estimate's position error against ``reference`` over the frames, one panel per world axis, after
    its own SE(3) (or Sim(3) ``with_scale``) Umeyama fit: errors that several trajectories share show as curves of
    one shape. Trajectories hold the reference's frames, in order; ``highlight`` is drawn in black. Written
    atomically."""
    from evo.core.geometry import umeyama_alignment
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    g = reference.positions
    fig = Figure(figsize=(12, 8), layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(3, 1, sharex=True)
    for name, estimate in estimates.items():
        if len(estimate) != len(reference):
            raise ConfigError(f"{name}: {len(estimate)} poses, the reference has {len(reference)}")
        p = estimate.positions
        R, t, s = umeyama_alignment(p.T, g.T, with_scale)
        style = {"color": "black", "lw": 1.5} if name == highlight else {"lw": 1}
        for axis, values in zip(axes, (s * p @ R.T + t - g).T, strict=True):
            axis.plot(100 * values, label=name, **style)
    for axis, label in zip(axes, "xyz", strict=True):
        axis.set_ylabel(f"error {label} (cm)")
        axis.grid(alpha=0.3)
    axes[0].legend(ncol=max(len(estimates), 1), fontsize="small")
    axes[-1].set_xlabel("frame")
    if title:
        axes[0].set_title(title)
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png")
    return write_bytes_atomic(path, buffer.getvalue())
