"""How much of the trackers' error against the ground truth they share: per-tracker ATE, ATE between trackers, and
the ATE of their averaged trajectories.

    python scripts/tracker_agreement.py [DATASET] [--methods slam,slam-orb,odometry]

If the trackers erred independently, averaging their trajectories would cut the ATE roughly as their mutual
disagreement allows; an average that scores no better than its members means the error they leave against the
ground truth is common to all of them (the ground truth's own, or the sensor's), not any one tracker's.
Averaging: translations by their mean, rotations by the nearest rotation to their sum (chordal mean).
"""

from __future__ import annotations

import argparse
import itertools
import json
import time
from pathlib import Path

import numpy as np

from semmap.datasets import open_dataset
from semmap.eval.trajectory import evaluate_trajectory
from semmap.poses.base import estimate_trajectory
from semmap.poses.file import trajectory_of_dataset
from semmap.poses.track import METHODS, make_tracker
from semmap.types import Trajectory, orthonormalize

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "7scenes-redkitchen"


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
    return round(100 * evaluate_trajectory(reference, estimate)["ate_rmse_m"], 3)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("dataset", nargs="?", type=Path, default=SHARED)
    ap.add_argument("--methods", default="slam,slam-orb,odometry", help=f"two or more of {', '.join(METHODS)}")
    args = ap.parse_args()
    methods = args.methods.split(",")
    unknown = sorted(set(methods) - set(METHODS))
    if unknown or len(methods) < 2:
        raise SystemExit(f"--methods needs two or more of {', '.join(METHODS)}; got {args.methods!r}")
    frames = [f for f in open_dataset(args.dataset) if f.T_world_cam is not None]
    if not frames:
        raise SystemExit(f"{args.dataset}: no frames with a ground-truth pose")
    gt = trajectory_of_dataset(frames)
    estimates = {}
    for method in methods:
        start = time.perf_counter()
        estimates[method] = estimate_trajectory(make_tracker(method), frames)
        ms = 1e3 * (time.perf_counter() - start) / len(frames)
        print(json.dumps({"method": method, "ate_cm": ate_cm(gt, estimates[method]), "ms_per_frame": round(ms)}),
              flush=True)
    for a, b in itertools.combinations(methods, 2):
        print(json.dumps({"between": [a, b], "ate_cm": ate_cm(estimates[a], estimates[b])}), flush=True)
    for size in range(2, len(methods) + 1):
        for group in itertools.combinations(methods, size):
            mean = chordal_mean([estimates[m] for m in group])
            print(json.dumps({"average_of": list(group), "ate_cm": ate_cm(gt, mean)}), flush=True)


if __name__ == "__main__":
    main()
