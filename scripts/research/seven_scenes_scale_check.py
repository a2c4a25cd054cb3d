"""Does the 7-Scenes depth calibration (f = 585 px, no depth distortion) give motion the length of the ground truth's?

For each depth focal length given (and each radial depth factor k: depth scaled by 1 + k r^2, r^2 = 1 at the
image corners, the shape of a Kinect's depth distortion), the colour camera's focal length is scaled with the
depth one (so colour lands on the same depth pixels as with the fitted registration), colour is registered
again, and

- frame pairs (i, i+gap) are aligned from the ground-truth relative pose by each dense cost (photometric only,
  geometric only, hybrid; photometric and hybrid also without the robust steps, ``_wide``): the summed length
  of the translations found over that of the ground truth's, the same for the rotation angles, and how far the
  photometric and geometric translations lie apart (median, mm);
- SIFT features matched in the registered colour of frame pairs (i, i+8) are compared with where the depth
  camera model puts them under the geometric (point-to-plane) alignment: the median over pairs of the fitted
  ratio of the features' displacements to the predicted ones (1: colour moves as the depth geometry says);
- depth clouds of frame pairs (i, i+30) are aligned by point-to-plane ICP: the mean residual of points within
  1 cm, a geometric, ground-truth-free sign of how well the focal length fits (a wrong one bends the views);
- with ``--slam`` the whole sequence is tracked by ``slam``: ATE after SE(3) alignment, the Sim(3) scale that maps
  the estimate onto the ground truth, and the ATE after that Sim(3) alignment.

An RGB-D tracker's trajectory has the metric scale of its depth camera model, so a Sim(3) scale away from 1, and
costs that disagree about how far the camera moved, point at a calibration that does not match the ground truth.

    python scripts/research/seven_scenes_scale_check.py [../shared/data/7scenes-redkitchen] [--focals 575,585,595,605]
        [--radials 0] [--gap 15] [--every 5] [--slam]
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import json
from pathlib import Path

import cv2
import numpy as np
import open3d as o3d
from seven_scenes_gt_check import cloud

from semmap.datasets import open_dataset
from semmap.eval.trajectory import evaluate_trajectory
from semmap.geometry import register_color
from semmap.poses.base import estimate_trajectory
from semmap.poses.dense_align import METHODS
from semmap.poses.file import trajectory_of_dataset
from semmap.poses.odometry import OdometryConfig
from semmap.poses.slam import DenseSlam
from semmap.types import Frame, invert_pose, orthonormalize, rotation_angle

SHARED = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "7scenes-redkitchen"


def with_depth_model(frames: list[Frame], focal: float, radial: float = 0.0) -> list[Frame]:
    """The frames as if the depth camera had focal length ``focal`` and its depth were off by the factor
    1 + ``radial`` r^2 (r^2 = 1 at the corners), colour registered again for it."""
    out = []
    for f in frames:
        if f.raw_color is None:
            raise SystemExit(f"frame {f.name} keeps no raw colour image: is this a 7-Scenes folder with the "
                             f"Kinect's intrinsics (f = 585 px)?")
        ratio = focal / f.intrinsics.fx
        cam = dataclasses.replace(f.intrinsics, fx=focal, fy=f.intrinsics.fy * ratio)
        colour_cam = dataclasses.replace(f.raw_color.camera, fx=f.raw_color.camera.fx * ratio,
                                         fy=f.raw_color.camera.fy * ratio)
        depth = f.depth
        if radial:
            h, w = depth.shape
            x = ((np.arange(w) - cam.cx) / cam.fx) ** 2
            y = ((np.arange(h) - cam.cy) / cam.fy) ** 2
            r2 = (y[:, None] + x[None, :]) / (max(x[0], x[-1]) + max(y[0], y[-1]))
            depth = (depth * (1.0 + radial * r2)).astype(depth.dtype)
        rgb = register_color(f.raw_color.image, depth, cam, colour_cam)
        out.append(dataclasses.replace(f, intrinsics=cam, depth=depth, rgb=rgb))
    return out


def relative_truth(a: Frame, b: Frame) -> np.ndarray:
    """Frame ``a``'s camera in frame ``b``'s by the ground truth, rotation re-orthonormalised (7-Scenes rotations
    are off orthonormal by up to 3e-4)."""
    T = invert_pose(b.T_world_cam) @ a.T_world_cam
    T[:3, :3] = orthonormalize(T[:3, :3])
    return T


def pair_motion(frames: list[Frame], gap: int, every: int) -> dict:
    """Summed translation length and rotation angle of each dense cost over the ground truth's, on pairs
    (i, i+gap)."""
    aligners = {m: OdometryConfig(method=m).aligner(frames[0].intrinsics) for m in METHODS}
    for m in ("hybrid", "intensity"):  # without the robust steps (the intensity Huber width stays wide)
        wide = OdometryConfig(method=m, iterations=(10, 5, 3), robust_iterations=())
        aligners[f"{m}_wide"] = wide.aligner(frames[0].intrinsics)
    found: dict[str, list] = {m: [] for m in aligners}
    truth = []
    for i in range(0, len(frames) - gap, every):
        a, b = frames[i], frames[i + gap]
        T_gt = relative_truth(a, b)
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


def colour_flow_ratio(frames: list[Frame], gap: int = 8, every: int = 10) -> float:
    """Median over pairs of how far SIFT features move in the registered colour images over how far the depth
    camera model moves them under the point-to-plane alignment (started from the ground truth)."""
    aligner = OdometryConfig(method="point_to_plane").aligner(frames[0].intrinsics)
    K = frames[0].intrinsics.K
    sift, matcher = cv2.SIFT_create(2000), cv2.BFMatcher()
    ratios = []
    for i in range(0, len(frames) - gap, every):
        a, b = frames[i], frames[i + gap]
        T = relative_truth(a, b)
        result = aligner.align(aligner.image(a.rgb, a.depth), aligner.image(b.rgb, b.depth), T)
        T = T if result is None else result.T
        ka, da = sift.detectAndCompute(cv2.cvtColor(a.rgb, cv2.COLOR_RGB2GRAY), None)
        kb, db = sift.detectAndCompute(cv2.cvtColor(b.rgb, cv2.COLOR_RGB2GRAY), None)
        if da is None or db is None or len(db) < 2:
            continue
        pairs = [m for m, n in matcher.knnMatch(da, db, k=2) if m.distance < 0.7 * n.distance]
        src = np.array([ka[m.queryIdx].pt for m in pairs]).reshape(-1, 2)
        dst = np.array([kb[m.trainIdx].pt for m in pairs]).reshape(-1, 2)
        col, row = np.round(src).astype(int).T
        z = a.depth[np.clip(row, 0, a.depth.shape[0] - 1), np.clip(col, 0, a.depth.shape[1] - 1)]
        ok = np.isfinite(z) & (z > 0.3) & (z < 3.5)
        rays = np.linalg.solve(K, np.column_stack([src, np.ones(len(src))]).T).T
        moved = (rays * z[:, None]) @ T[:3, :3].T + T[:3, 3]
        predicted = (moved @ K.T)[:, :2] / moved[:, 2:3] - src
        measured = dst - src
        ok &= (np.linalg.norm(predicted, axis=1) > 5) & (np.linalg.norm(measured - predicted, axis=1) < 15)
        if ok.sum() >= 30:
            P, F = predicted[ok], measured[ok]
            ratios.append(float((P * F).sum() / (P * P).sum()))
    return float(np.median(ratios)) if ratios else float("nan")


def icp_residual(frames: list[Frame], gap: int = 30, every: int = 10) -> float:
    """Mean residual (metres) of depth points within 1 cm after point-to-plane ICP of pairs (i, i+gap)."""
    residuals = []
    for i in range(0, len(frames) - gap, every):
        a, b = frames[i], frames[i + gap]
        T = relative_truth(a, b)
        ca, cb = cloud(a), cloud(b)
        T = o3d.pipelines.registration.registration_icp(
            ca, cb, 0.05, T, o3d.pipelines.registration.TransformationEstimationPointToPlane()).transformation
        residuals.append(o3d.pipelines.registration.evaluate_registration(ca, cb, 0.01, T).inlier_rmse)
    return float(np.mean(residuals))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("dataset", nargs="?", type=Path, default=SHARED)
    ap.add_argument("--focals", default="575,585,595,605", help="depth focal lengths to try (pixels)")
    ap.add_argument("--radials", default="0", help="radial depth factors k to try at each focal length")
    ap.add_argument("--gap", type=int, default=15, help="frames between the two frames of a pair")
    ap.add_argument("--every", type=int, default=5, help="a pair starts every k-th frame")
    ap.add_argument("--slam", action="store_true", help="also track the whole sequence with slam")
    args = ap.parse_args()
    frames = [f for f in open_dataset(args.dataset) if f.T_world_cam is not None]
    gt = trajectory_of_dataset(frames)
    for focal, radial in itertools.product(*(map(float, v.split(",")) for v in (args.focals, args.radials))):
        moved = with_depth_model(frames, focal, radial)
        row = {"depth_focal_px": focal, "depth_radial": radial, **pair_motion(moved, args.gap, args.every),
               "colour_flow_vs_depth": round(colour_flow_ratio(moved), 4),
               "icp_residual_mm": round(1e3 * icp_residual(moved), 3)}
        if args.slam:
            scores = evaluate_trajectory(gt, estimate_trajectory(DenseSlam(), moved))
            row |= {"slam_ate_m": round(scores["ate_rmse_m"], 5), "slam_sim3_scale": round(scores["sim3_scale"], 4),
                    "slam_ate_sim3_m": round(scores["ate_sim3_rmse_m"], 5)}
        print(json.dumps(row), flush=True)


if __name__ == "__main__":
    main()
