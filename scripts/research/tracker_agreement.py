"""How much of the trackers' error against the ground truth they share: per-tracker ATE, ATE between trackers, the
part of the error each pair has in common, and the ATE of averaged trajectories.

    python scripts/research/tracker_agreement.py [DATASET] [--methods slam,slam-orb,odometry,slam-features,open3d-f2f]
        [--plot errors.png]

Read each tracker's error as a vector over the frames: a common part c plus its own part. Two trackers with ATEs
a and b that lie d apart then share |c|^2 ~ (a^2 + b^2 - d^2) / 2 (their errors' dot product; exact when their own
parts are independent). Trackers with unrelated costs that still share most of their error against the ground
truth point at an error of the ground truth, or of the sensor, not of any one tracker. Averaged trajectories
(translations by their mean, rotations by the nearest rotation to their sum) show the same directly: own parts
average out, the common part stays. Each tracker's ATE is also given with a fixed offset in the camera's frame fitted
to the ground truth: a common part caused by the ground truth describing another point of the sensor would vanish
with the same offset for every tracker. The offset shared by all is fitted too, and each tracker's offset fitted on
one half of the frames is tried on the other half.
"""

from __future__ import annotations

import argparse
import itertools
import json
import time
from pathlib import Path

import numpy as np
from evo.core.geometry import umeyama_alignment
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from semmap.datasets import open_dataset
from semmap.eval.trajectory import evaluate_trajectory, plot_position_errors
from semmap.poses.base import estimate_trajectory
from semmap.poses.file import trajectory_of_dataset
from semmap.poses.track import METHODS, make_tracker
from semmap.types import Trajectory, orthonormalize

#: `slam-features` (ORB features, PnP, bundle adjustment) and `open3d-f2f` (Open3D's code) share no cost or code with
#: the dense trackers; `slam-orb` refines its feature poses with the dense aligner.
DEFAULT_METHODS = "slam,slam-orb,odometry,slam-features,open3d-f2f"
SHARED = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "7scenes-redkitchen"


def chordal_mean(trajectories: list[Trajectory]) -> Trajectory:
    """Pose-wise average of trajectories over the same frames: mean translation, nearest rotation to the summed
    rotations."""
    poses = np.stack([t.poses for t in trajectories])
    out = np.tile(np.eye(4), (poses.shape[1], 1, 1))
    out[:, :3, 3] = poses[:, :, :3, 3].mean(axis=0)
    out[:, :3, :3] = [orthonormalize(R) for R in poses[:, :, :3, :3].sum(axis=0)]
    first = trajectories[0]
    return Trajectory(first.timestamps, out, first.names)


def ate_cm(reference: Trajectory, estimate: Trajectory) -> float:
    """ATE RMSE (cm) after SE(3) alignment."""
    return 100 * evaluate_trajectory(reference, estimate)["ate_rmse_m"]


def ates_with_camera_offset(reference: Trajectory, estimates: list[Trajectory]) -> tuple[list[float], np.ndarray]:
    """ATE RMSE (cm) of each estimate when, besides each one's SE(3) alignment, one fixed offset b in the camera's
    own frame, shared by all, is fitted (positions p_i + R_i b), and that offset (cm). If the ground truth described
    another point of the sensor than the depth camera's centre (the colour camera's, say), the same b would help
    every tracker. The estimates hold the reference's frames, in order. Joint nonlinear least squares, started
    from Umeyama alignments and b = 0."""
    g = reference.positions
    starts = [umeyama_alignment(e.positions.T, g.T) for e in estimates]
    x0 = np.concatenate([np.r_[Rotation.from_matrix(R).as_rotvec(), t] for R, t, _ in starts] + [np.zeros(3)])

    def positions(x: np.ndarray) -> list[np.ndarray]:
        b = x[-3:]
        out = []
        for k, e in enumerate(estimates):
            R, t = Rotation.from_rotvec(x[6 * k: 6 * k + 3]).as_matrix(), x[6 * k + 3: 6 * k + 6]
            out.append((e.positions + e.poses[:, :3, :3] @ b) @ R.T + t)
        return out

    fit = least_squares(lambda x: np.concatenate([(q - g).ravel() for q in positions(x)]), x0)
    rmse = [100 * float(np.sqrt(np.mean(np.sum((q - g) ** 2, axis=1)))) for q in positions(fit.x)]
    return rmse, 100 * fit.x[-3:]


def offset_transfer(reference: Trajectory, estimate: Trajectory) -> list[list[float]]:
    """A camera offset fitted on one half of the frames, applied to the other half: [ATE without, ATE with] (cm) of
    the second half with the first half's offset, then the other way round. An offset that is a property of the
    sensor carries over; one that only absorbs a slow error does not."""
    n = len(estimate) // 2
    out = []
    for fit, test in ((slice(0, n), slice(n, None)), (slice(n, None), slice(0, n))):
        _, b = ates_with_camera_offset(part(reference, fit), [part(estimate, fit)])
        moved = part(estimate, test)
        poses = moved.poses.copy()
        poses[:, :3, 3] += poses[:, :3, :3] @ (b / 100)
        shifted = Trajectory(moved.timestamps, poses, moved.names)
        out.append([round(ate_cm(part(reference, test), moved), 3), round(ate_cm(part(reference, test), shifted), 3)])
    return out


def part(trajectory: Trajectory, frames: slice) -> Trajectory:
    """The poses of ``frames`` only."""
    return Trajectory(trajectory.timestamps[frames], trajectory.poses[frames], trajectory.names[frames])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("dataset", nargs="?", type=Path, default=SHARED)
    ap.add_argument("--methods", default=DEFAULT_METHODS, help=f"two or more of {', '.join(METHODS)}")
    ap.add_argument("--plot", type=Path, help="also plot each tracker's error over the frames to this PNG")
    args = ap.parse_args()
    methods = args.methods.split(",")
    unknown = sorted(set(methods) - set(METHODS))
    if unknown or len(methods) < 2:
        raise SystemExit(f"--methods needs two or more of {', '.join(METHODS)}; got {args.methods!r}")
    frames = [f for f in open_dataset(args.dataset) if f.T_world_cam is not None]
    if not frames:
        raise SystemExit(f"{args.dataset}: no frames with a ground-truth pose")
    gt = trajectory_of_dataset(frames)
    estimates, ates = {}, {}
    for method in methods:
        start = time.perf_counter()
        estimates[method] = estimate_trajectory(make_tracker(method), frames)
        ms = 1e3 * (time.perf_counter() - start) / len(frames)
        ates[method] = ate_cm(gt, estimates[method])
        [offset_ate], offset = ates_with_camera_offset(gt, [estimates[method]])
        print(json.dumps({"method": method, "ate_cm": round(ates[method], 3), "ms_per_frame": round(ms),
                          "ate_with_camera_offset_cm": round(offset_ate, 3),
                          "camera_offset_cm": [round(float(v), 2) for v in offset],
                          "offset_from_other_half_cm": offset_transfer(gt, estimates[method])}), flush=True)
    offset_ates, offset = ates_with_camera_offset(gt, [estimates[m] for m in methods])
    print(json.dumps({"one_camera_offset_for_all_cm": [round(float(v), 2) for v in offset],
                      "ate_cm": {m: round(a, 3) for m, a in zip(methods, offset_ates, strict=True)}}), flush=True)
    for a, b in itertools.combinations(methods, 2):
        apart = ate_cm(estimates[a], estimates[b])
        shared = (ates[a] ** 2 + ates[b] ** 2 - apart ** 2) / 2
        print(json.dumps({"between": [a, b], "ate_cm": round(apart, 3),
                          "shared_cm": round(float(np.sqrt(max(shared, 0.0))), 2),
                          "correlation": round(shared / (ates[a] * ates[b]), 2)}), flush=True)
    if args.plot:
        plot_position_errors(args.plot, gt, estimates,
                             title="position error against the ground truth, each tracker aligned by SE(3)")
    groups = list(itertools.combinations(methods, 2)) + ([tuple(methods)] if len(methods) > 2 else [])
    for group in groups:
        mean = chordal_mean([estimates[m] for m in group])
        print(json.dumps({"average_of": list(group), "ate_cm": round(ate_cm(gt, mean), 3)}), flush=True)


if __name__ == "__main__":
    main()
