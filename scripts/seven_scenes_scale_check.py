"""Does the 7-Scenes depth calibration (f = 585 px) give motion the length of the ground truth's?

For each depth focal length given, the colour camera's focal length is scaled with it (so colour lands on the same
depth pixels as with the fitted registration), colour is registered again, and

- frame pairs (i, i+gap) are aligned from the ground-truth relative pose by each dense cost (photometric only,
  geometric only, hybrid): the summed length of the translations found over that of the ground truth's, the same
  for the rotation angles, and how far the photometric and geometric translations lie apart (median, mm);
- with ``--slam`` the whole sequence is tracked by ``slam``: ATE after SE(3) alignment, the Sim(3) scale that maps
  the estimate onto the ground truth, and the ATE after that Sim(3) alignment.

An RGB-D tracker's trajectory has the metric scale of its depth camera model, so a Sim(3) scale away from 1, and
costs that disagree about how far the camera moved, point at a calibration that does not match the ground truth.

    python scripts/seven_scenes_scale_check.py [../shared/data/7scenes-redkitchen] [--focals 575,585,595,605]
        [--gap 15] [--every 5] [--slam]
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import numpy as np

from semmap.datasets import open_dataset
from semmap.eval.trajectory import evaluate_trajectory
from semmap.geometry import register_color
from semmap.poses.base import estimate_trajectory
from semmap.poses.dense_align import METHODS
from semmap.poses.file import trajectory_of_dataset
from semmap.poses.odometry import OdometryConfig
from semmap.poses.slam import DenseSlam
from semmap.types import Frame, invert_pose, orthonormalize, rotation_angle

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "7scenes-redkitchen"


def with_depth_focal(frames: list[Frame], focal: float) -> list[Frame]:
    """The frames as if the depth camera had focal length ``focal``, colour registered again for it."""
    out = []
    for f in frames:
        if f.raw_color is None:
            raise SystemExit(f"frame {f.name} keeps no raw colour image: is this a 7-Scenes folder with the "
                             f"Kinect's intrinsics (f = 585 px)?")
        ratio = focal / f.intrinsics.fx
        cam = dataclasses.replace(f.intrinsics, fx=focal, fy=f.intrinsics.fy * ratio)
        colour_cam = dataclasses.replace(f.raw_color.camera, fx=f.raw_color.camera.fx * ratio,
                                         fy=f.raw_color.camera.fy * ratio)
        rgb = register_color(f.raw_color.image, f.depth, cam, colour_cam)
        out.append(dataclasses.replace(f, intrinsics=cam, rgb=rgb))
    return out


def pair_motion(frames: list[Frame], gap: int, every: int) -> dict:
    """Summed translation length and rotation angle of each dense cost over the ground truth's, on pairs
    (i, i+gap)."""
    aligners = {m: OdometryConfig(method=m).aligner(frames[0].intrinsics) for m in METHODS}
    found: dict[str, list] = {m: [] for m in METHODS}
    truth = []
    for i in range(0, len(frames) - gap, every):
        a, b = frames[i], frames[i + gap]
        T_gt = invert_pose(b.T_world_cam) @ a.T_world_cam  # a's camera in b's
        T_gt[:3, :3] = orthonormalize(T_gt[:3, :3])  # 7-Scenes rotations are off orthonormal by up to 3e-4
        truth.append(T_gt)
        for m, aligner in aligners.items():
            result = aligner.align(aligner.image(a.rgb, a.depth), aligner.image(b.rgb, b.depth), T_gt)
            found[m].append(None if result is None else result.T)
    truth_len = np.array([np.linalg.norm(T[:3, 3]) for T in truth])
    truth_angle = np.array([rotation_angle(T[:3, :3]) for T in truth])
    row = {"pairs": len(truth)}
    for m, Ts in found.items():
        ok = [k for k, T in enumerate(Ts) if T is not None]
        length = sum(np.linalg.norm(Ts[k][:3, 3]) for k in ok)
        angle = sum(rotation_angle(Ts[k][:3, :3]) for k in ok)
        row[f"length_ratio_{m}"] = round(float(length / truth_len[ok].sum()), 4)
        row[f"angle_ratio_{m}"] = round(float(angle / truth_angle[ok].sum()), 4)
    pairs = zip(found["intensity"], found["point_to_plane"], strict=True)
    apart = [np.linalg.norm(p[:3, 3] - g[:3, 3]) for p, g in pairs if p is not None and g is not None]
    row["photometric_vs_geometric_mm"] = round(1e3 * float(np.median(apart)), 1)
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("dataset", nargs="?", type=Path, default=SHARED)
    ap.add_argument("--focals", default="575,585,595,605", help="depth focal lengths to try (pixels)")
    ap.add_argument("--gap", type=int, default=15, help="frames between the two frames of a pair")
    ap.add_argument("--every", type=int, default=5, help="a pair starts every k-th frame")
    ap.add_argument("--slam", action="store_true", help="also track the whole sequence with slam")
    args = ap.parse_args()
    frames = [f for f in open_dataset(args.dataset) if f.T_world_cam is not None]
    gt = trajectory_of_dataset(frames)
    for focal in (float(v) for v in args.focals.split(",")):
        moved = with_depth_focal(frames, focal)
        row = {"depth_focal_px": focal, **pair_motion(moved, args.gap, args.every)}
        if args.slam:
            scores = evaluate_trajectory(gt, estimate_trajectory(DenseSlam(), moved))
            row |= {"slam_ate_m": round(scores["ate_rmse_m"], 5), "slam_sim3_scale": round(scores["sim3_scale"], 4),
                    "slam_ate_sim3_m": round(scores["ate_sim3_rmse_m"], 5)}
        print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
