"""The trackers and the 7-Scenes ground truth measured against a second, independent reference: the SfM pseudo
ground truth of Brachmann et al., "On the Limits of Pseudo Ground Truth in Visual Camera Re-localisation"
(ICCV 2021).

    python scripts/research/seven_scenes_sfm_reference.py PGT [DATASET] [--sequence seq-01]
        [--methods slam,slam-orb,odometry,slam-features,open3d-f2f] [--trajectories DIR] [--plot errors.png]

PGT is their pose file for the scene, ``pgt/sfm/7scenes/redkitchen_train.txt`` of
github.com/tsattler/visloc_pseudo_gt_limitations (seq-01, whose first 600 frames are ``../shared``'s redkitchen
frames, is a training sequence). Each line is ``seq-XX/frame-NNNNNN.color.png qw qx qy qz tx ty tz [f]``, a
COLMAP world-to-camera pose of the colour camera from a Structure-from-Motion reconstruction of the colour images
alone. The 7-Scenes ground truth (KinectFusion on the depth images, "D-SLAM") and this one share no method, so
where both are trusted to some accuracy, their disagreement bounds it.

Trackers estimate the depth camera; its poses are moved to the colour camera with the offset that the reader's
colour registration uses (``SEVEN_SCENES_COLOR_CAMERA``, fitted on image edges, no ground truth). SfM has no scale
of its own, so the Sim(3)-aligned ATE is the fair one against it; the SE(3) one is printed too. Printed, one JSON
line each: the D-SLAM ground truth against SfM; each tracker against both references, then its ratios to
``open3d-f2f``; and the RMS disagreement of relative rotations over 5 and 30 frames between every two of them
(rotation angles need no alignment and no scale). ``--trajectories DIR`` reads ``DIR/METHOD.txt`` (TUM, as
``semmap track`` writes) where it exists and writes the trajectories it had to track there.
"""

from __future__ import annotations

import argparse
import json
import re
import time
from pathlib import Path

import numpy as np

from semmap.datasets import open_dataset
from semmap.datasets.sevenscenes import FRAME_RATE, SEVEN_SCENES_COLOR_CAMERA
from semmap.errors import FormatError
from semmap.eval.trajectory import evaluate_trajectory, plot_position_errors, rotation_disagreement_deg
from semmap.io.trajectory import read_trajectory, write_trajectory
from semmap.poses.base import estimate_trajectory
from semmap.poses.file import trajectory_of_dataset
from semmap.poses.track import METHODS, make_tracker
from semmap.types import Trajectory, invert_pose, make_pose, quat_xyzw_to_rot

DEFAULT_METHODS = "slam,slam-orb,odometry,slam-features,open3d-f2f"
SHARED = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "7scenes-redkitchen"
PEER = "open3d-f2f"
DSLAM = "D-SLAM ground truth"
LINE = re.compile(r"^(?P<seq>[^/\s]+)/frame-(?P<frame>\d+)\.color\.\w+$")


def read_pose_list(path: Path, sequence: str) -> dict[int, np.ndarray]:
    """Camera-to-world poses by frame number of ``sequence``'s lines in a COLMAP-convention pose list (``name qw qx
    qy qz tx ty tz [f]``, ``p_cam = R p_world + t``); other sequences' lines are skipped. A malformed line of the
    sequence is a :class:`FormatError` naming the file and line."""
    try:
        text = Path(path).read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise FormatError(f"{path}: cannot read the pose list: {exc}") from None
    poses: dict[int, np.ndarray] = {}
    for number, line in enumerate(text.splitlines(), start=1):
        fields = line.split()
        if not fields or fields[0].startswith("#"):
            continue
        match = LINE.match(fields[0])
        if match is None or match["seq"] != sequence:
            continue
        where = f"{path}:{number}"
        if len(fields) not in (8, 9):
            raise FormatError(f"{where}: expected 'name qw qx qy qz tx ty tz [f]', got {len(fields)} fields")
        try:
            qw, qx, qy, qz, tx, ty, tz = (float(v) for v in fields[1:8])
        except ValueError:
            raise FormatError(f"{where}: pose values are not all numbers") from None
        q = np.array([qx, qy, qz, qw])
        if not np.isfinite(q).all() or abs(np.linalg.norm(q) - 1) > 1e-3:
            raise FormatError(f"{where}: quaternion norm {np.linalg.norm(q):.6f}, expected 1 (order qw qx qy qz)")
        frame = int(match["frame"])
        if frame in poses:
            raise FormatError(f"{where}: {fields[0]} appears twice")
        poses[frame] = invert_pose(make_pose(quat_xyzw_to_rot(q), [tx, ty, tz]))
    if not poses:
        raise FormatError(f"{path}: no poses of sequence {sequence!r} (lines 'seq-XX/frame-NNNNNN.color.png ...')")
    return poses


def as_trajectory(poses: dict[int, np.ndarray]) -> Trajectory:
    """Poses by frame number as a trajectory timed like the 7-Scenes reader's frames (frame / 30 s)."""
    frames = sorted(poses)
    return Trajectory(np.array(frames) / FRAME_RATE, np.stack([poses[f] for f in frames]),
                      tuple(f"frame-{f:06d}" for f in frames))


def to_color_camera(trajectory: Trajectory) -> Trajectory:
    """Depth-camera poses moved to the colour camera (``X_color = X_depth + t``: its centre is at -t)."""
    shift = make_pose(np.eye(3), -np.asarray(SEVEN_SCENES_COLOR_CAMERA.t_color_depth))
    return Trajectory(trajectory.timestamps, trajectory.poses @ shift, trajectory.names)


def common_frames(*trajectories: Trajectory) -> list[Trajectory]:
    """Each trajectory reduced to the timestamps all of them have (the SfM file may lack frames)."""
    keys = [np.round(t.timestamps * FRAME_RATE).astype(int) for t in trajectories]
    shared = sorted(set.intersection(*(set(k.tolist()) for k in keys)))
    out = []
    for t, k in zip(trajectories, keys, strict=True):
        index = {f: i for i, f in enumerate(k.tolist())}
        rows = [index[f] for f in shared]
        out.append(Trajectory(t.timestamps[rows], t.poses[rows], tuple(f"frame-{f:06d}" for f in shared)))
    return out


def trajectory_of(method: str, frames: list, folder: Path | None) -> Trajectory:
    """``folder/METHOD.txt`` where it exists, else the tracker's trajectory (written there when a folder is given)."""
    path = folder / f"{method}.txt" if folder else None
    if path is not None and path.is_file():
        return read_trajectory(path)
    start = time.perf_counter()
    trajectory = estimate_trajectory(make_tracker(method), frames)
    print(json.dumps({"tracked": method, "ms_per_frame": round(1e3 * (time.perf_counter() - start) / len(frames))}),
          flush=True)
    if path is not None:
        write_trajectory(path, trajectory)
    return trajectory


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("pgt", type=Path, help="SfM pose file, e.g. pgt/sfm/7scenes/redkitchen_train.txt")
    ap.add_argument("dataset", nargs="?", type=Path, default=SHARED)
    ap.add_argument("--sequence", default="seq-01", help="the dataset's sequence in the pose file (default seq-01)")
    ap.add_argument("--methods", default=DEFAULT_METHODS, help=f"any of {', '.join(METHODS)}")
    ap.add_argument("--trajectories", type=Path, help="folder of METHOD.txt trajectories to reuse / write")
    ap.add_argument("--plot", type=Path, help="also plot every trajectory's error against SfM to this PNG")
    args = ap.parse_args()
    methods = [m for m in args.methods.split(",") if m]
    unknown = sorted(set(methods) - set(METHODS))
    if unknown:
        raise SystemExit(f"--methods: unknown {', '.join(unknown)}; known: {', '.join(METHODS)}")
    try:
        sfm_all = as_trajectory(read_pose_list(args.pgt, args.sequence))
    except FormatError as exc:
        raise SystemExit(str(exc)) from None
    frames = [f for f in open_dataset(args.dataset) if f.T_world_cam is not None]
    if not frames:
        raise SystemExit(f"{args.dataset}: no frames with a ground-truth pose")
    if args.trajectories:
        args.trajectories.mkdir(parents=True, exist_ok=True)
    depth_poses = {DSLAM: trajectory_of_dataset(frames)}
    depth_poses.update({m: trajectory_of(m, frames, args.trajectories) for m in methods})
    names = list(depth_poses)
    sfm, *moved = common_frames(sfm_all, *(to_color_camera(t) for t in depth_poses.values()))
    colour = dict(zip(names, moved, strict=True))
    dslam = colour[DSLAM]
    print(json.dumps({"sequence": args.sequence, "frames": len(sfm), "sfm_poses_in_file": len(sfm_all),
                      "dataset_frames": len(frames)}), flush=True)
    scores = {}
    for name in names:
        against_sfm = evaluate_trajectory(sfm, colour[name])
        scores[name] = {"ate_dslam_cm": 100 * evaluate_trajectory(dslam, colour[name])["ate_rmse_m"],
                        "ate_sfm_cm": 100 * against_sfm["ate_rmse_m"],
                        "ate_sfm_sim3_cm": 100 * against_sfm["ate_sim3_rmse_m"]}
        scale = against_sfm["sim3_scale"]
        print(json.dumps({"trajectory": name, **{k: round(v, 3) for k, v in scores[name].items()},
                          "sim3_scale_to_sfm": round(scale, 4)}), flush=True)
    if PEER in scores:  # ratios from unrounded ATEs, rounded only when printed
        for name in names[1:]:
            print(json.dumps({"trajectory": name, "ratio_to_" + PEER: {
                key: round(value / scores[PEER][key], 3) for key, value in scores[name].items()}}), flush=True)
    everything = {"SfM pseudo ground truth": sfm, **colour}
    for span in (5, 30):
        labels = list(everything)
        matrix = [[round(rotation_disagreement_deg(everything[a], everything[b], span), 3) for b in labels]
                  for a in labels]
        print(json.dumps({"rotation_disagreement_deg": {"frames": span, "order": labels, "matrix": matrix}}),
              flush=True)
    if args.plot:
        plot_position_errors(args.plot, sfm, colour, with_scale=True, highlight=DSLAM,
                             title="position error against the SfM pseudo ground truth (Brachmann et al. 2021), "
                                   "Sim(3) aligned")


if __name__ == "__main__":
    main()
