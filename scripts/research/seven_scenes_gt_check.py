"""How well does the 7-Scenes ground truth align the depth it was made from? For frame pairs (i, i+gap) it
compares the ground-truth relative pose with the pose point-to-plane ICP finds when started from it, and the
depth residuals of both.

7-Scenes poses come from KinectFusion, not from a motion-capture system. Where ICP, started at the ground truth,
moves away from it and leaves the two depth clouds closer than the ground truth does, the ground truth itself is
off by that much; this bounds how low any tracker's ATE against it can meaningfully go.

    python scripts/research/seven_scenes_gt_check.py [../shared/data/7scenes-redkitchen] [--gap 5] [--every 20]
        [--worst 5]

``--gap 1 --every 1`` checks every consecutive pair; ``--worst N`` lists the N pairs ICP corrects most, with the
ground truth's own step between the two frames (a glitch shows as a step far larger than its neighbours' that ICP
takes back).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import open3d as o3d

from semmap.datasets import open_dataset
from semmap.geometry import backproject
from semmap.types import invert_pose, orthonormalize, pose_change

SHARED = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "7scenes-redkitchen"
VOXEL = 0.01  #: metres; clouds are voxel-filtered to this before ICP
MAX_DEPTH = 3.5  #: metres; farther Kinect depth is too noisy to judge a pose by


def cloud(frame) -> o3d.geometry.PointCloud:
    pts, _ = backproject(frame.depth, frame.intrinsics, max_depth=MAX_DEPTH)
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts.astype(np.float64))).voxel_down_sample(VOXEL)
    pcd.estimate_normals(o3d.geometry.KDTreeSearchParamHybrid(radius=5 * VOXEL, max_nn=30))
    return pcd


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("dataset", nargs="?", type=Path, default=SHARED)
    ap.add_argument("--gap", type=int, default=5, help="frames between the two frames of a pair")
    ap.add_argument("--every", type=int, default=20, help="a pair starts every k-th frame")
    ap.add_argument("--worst", type=int, default=5, help="list this many pairs with the largest ICP correction")
    args = ap.parse_args()
    frames = {f.index: f for f in open_dataset(args.dataset)}
    p2p = o3d.pipelines.registration.TransformationEstimationPointToPlane()
    rows = []
    for i in range(0, max(frames) - args.gap + 1, args.every):
        a, b = frames.get(i), frames.get(i + args.gap)
        if a is None or b is None:
            continue
        ca, cb = cloud(a), cloud(b)
        T_gt = invert_pose(a.T_world_cam) @ b.T_world_cam  # b's camera in a's
        T_gt[:3, :3] = orthonormalize(T_gt[:3, :3])  # 7-Scenes rotations are off orthonormal by up to 3e-4
        T = T_gt
        for threshold in (3 * VOXEL, 2 * VOXEL, VOXEL):
            T = o3d.pipelines.registration.registration_icp(cb, ca, threshold, T, p2p).transformation
        at_gt = o3d.pipelines.registration.evaluate_registration(cb, ca, 2 * VOXEL, T_gt)
        at_icp = o3d.pipelines.registration.evaluate_registration(cb, ca, 2 * VOXEL, T)
        dist, angle = pose_change(T_gt, T)
        step, _ = pose_change(np.eye(4), T_gt)
        rows.append((dist, angle, at_gt.inlier_rmse, at_icp.inlier_rmse, at_gt.fitness, at_icp.fitness, i, step))
    r = np.array(rows)
    worst = [{"frames": [int(row[6]), int(row[6]) + args.gap], "gt_step_mm": round(1e3 * row[7], 1),
              "icp_moves_gt_by_mm": round(1e3 * row[0], 1), "depth_rmse_mm_gt": round(1e3 * row[2], 2),
              "depth_rmse_mm_icp": round(1e3 * row[3], 2)} for row in r[np.argsort(-r[:, 0])[: args.worst]]]
    print(json.dumps({
        "pairs": len(r), "gap_frames": args.gap,
        "icp_moves_gt_by_mm": {"median": round(1e3 * float(np.median(r[:, 0])), 2),
                               "p90": round(1e3 * float(np.percentile(r[:, 0], 90)), 2)},
        "icp_turns_gt_by_deg": {"median": round(float(np.median(r[:, 1])), 3),
                                "p90": round(float(np.percentile(r[:, 1], 90)), 3)},
        "depth_rmse_mm": {"ground_truth": round(1e3 * float(np.median(r[:, 2])), 2),
                          "icp": round(1e3 * float(np.median(r[:, 3])), 2)},
        "inlier_share": {"ground_truth": round(float(np.median(r[:, 4])), 3),
                         "icp": round(float(np.median(r[:, 5])), 3)},
        "icp_better_in_share_of_pairs": round(float(np.mean(r[:, 3] < r[:, 2])), 3),
        "gt_step_mm_median": round(1e3 * float(np.median(r[:, 7])), 1),
        "worst_pairs": worst,
    }, indent=1))


if __name__ == "__main__":
    main()
