"""Run the built-in RGB-D SLAM on a dataset and print ATE, RPE, ms/frame, keyframes, loops and lost frames.

    python scripts/research/slam_check.py /work/shared/data/7scenes-redkitchen [--no-loop] [--max-frames N]
    python scripts/research/slam_check.py sim:desk [--frames 300] [--cache /tmp/slamcache]

Frames are read (or rendered) into memory first, so the timing covers the SLAM only. ``--cache`` keeps the
decoded frames in an .npz per dataset to skip reading/rendering on the next run.
"""

from __future__ import annotations

import argparse
import itertools
import time
from pathlib import Path

import numpy as np
from evo.core.geometry import umeyama_alignment

from semmap.poses.slam import RgbdSlam, SlamConfig
from semmap.types import CameraIntrinsics, Frame, rotation_angle


def load_frames(spec: str, frames: int, max_frames: int | None, cache: Path | None) -> list[Frame]:
    """Frames of ``spec`` (a dataset folder or ``sim:<trajectory>``), optionally via an .npz cache."""
    key = spec.replace("/", "_").replace(":", "_") + f"_{frames}_{max_frames}"
    path = cache / f"{key}.npz" if cache else None
    if path is not None and path.is_file():
        d = dict(np.load(path))
        cam = CameraIntrinsics(*[int(v) for v in d["K"][:2]], *[float(v) for v in d["K"][2:]])
        return [Frame(index=i, timestamp=float(d["ts"][i]), rgb=d["rgb"][i], depth=d["depth"][i], intrinsics=cam,
                      T_world_cam=d["T"][i], name=str(d["names"][i])) for i in range(len(d["ts"]))]
    if spec.startswith("sim:"):
        from semmap.datasets.simulated import SimulatedDataset

        ds = SimulatedDataset.default(scene_seed=0, trajectory=spec[4:], frames=frames)
        out = list(itertools.islice(iter(ds), max_frames))
    else:
        from semmap.datasets import open_dataset

        out = list(open_dataset(spec, max_frames=max_frames))
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        c = out[0].intrinsics
        np.savez(path, rgb=np.array([f.rgb for f in out]), depth=np.array([f.depth for f in out]),
                 T=np.array([f.T_world_cam for f in out]), ts=np.array([f.timestamp for f in out]),
                 names=np.array([f.name for f in out]), K=np.array([c.width, c.height, c.fx, c.fy, c.cx, c.cy]))
    return out


def ate_rmse(est: np.ndarray, gt: np.ndarray) -> float:
    """Absolute trajectory error (RMSE, metres) after SE(3) alignment of the estimate to ground truth."""
    R, t, _ = umeyama_alignment(est[:, :3, 3].T, gt[:, :3, 3].T)
    aligned = est[:, :3, 3] @ R.T + t
    return float(np.sqrt(((aligned - gt[:, :3, 3]) ** 2).sum(1).mean()))


def rpe(est: np.ndarray, gt: np.ndarray, delta: int) -> tuple[float, float]:
    """Relative pose error over ``delta`` frames: translation RMSE (m) and rotation RMSE (deg)."""
    def rel(P: np.ndarray) -> np.ndarray:
        return np.linalg.inv(P[:-delta]) @ P[delta:]
    E = np.linalg.inv(rel(gt)) @ rel(est)
    t = np.linalg.norm(E[:, :3, 3], axis=1)
    ang = np.degrees([rotation_angle(e) for e in E])  # atan2: blind to the ground truth's slight non-orthonormality
    return float(np.sqrt((t**2).mean())), float(np.sqrt((ang**2).mean()))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("dataset")
    ap.add_argument("--frames", type=int, default=300, help="frames of a simulated sequence")
    ap.add_argument("--max-frames", type=int, default=None)
    ap.add_argument("--no-loop", action="store_true", help="disable loop closure")
    ap.add_argument("--no-ba", action="store_true", help="disable local bundle adjustment")
    ap.add_argument("--dense", choices=("off", "keyframes", "frames"), default=SlamConfig.dense_refine,
                    help="dense refinement of the feature-tracked poses (SlamConfig.dense_refine)")
    ap.add_argument("--cache", type=Path, default=None)
    ap.add_argument("--repeat", type=int, default=1, help="runs (the best time is reported)")
    ap.add_argument("--profile", action="store_true")
    args = ap.parse_args()
    frames = load_frames(args.dataset, args.frames, args.max_frames, args.cache)
    cfg = SlamConfig(loop_closure=not args.no_loop, local_ba=not args.no_ba, dense_refine=args.dense)
    best = None
    for _ in range(args.repeat):
        slam = RgbdSlam(cfg)
        if args.profile:
            import cProfile
            import pstats

            prof = cProfile.Profile()
            prof.enable()
        t0 = time.perf_counter()
        for f in frames:
            slam.track(f)
        wall = time.perf_counter() - t0
        if args.profile:
            prof.disable()
            pstats.Stats(prof).sort_stats("cumulative").print_stats(25)
        best = wall if best is None else min(best, wall)
    traj = slam.trajectory()
    gt_by_name = {f.name: f.T_world_cam for f in frames}
    gt = np.array([gt_by_name[n] for n in traj.names])
    s = slam.stats
    n = len(frames)
    print(f"{args.dataset}: frames={n} tracked={len(traj)} lost={s.lost} relocs={s.relocalisations} "
          f"keyframes={s.keyframes} loops={s.loops} loop={'off' if args.no_loop else 'on'} dense={args.dense} "
          f"dense_refined={s.dense_refined} dense_fallbacks={s.dense_fallbacks}")
    rt, rr = rpe(traj.poses, gt, 1)
    rt30, rr30 = rpe(traj.poses, gt, 30) if len(traj) > 30 else (float("nan"), float("nan"))
    print(f"  ATE RMSE {ate_rmse(traj.poses, gt) * 100:.2f} cm | RPE(1 frame) {rt * 1000:.2f} mm {rr:.3f} deg"
          f" | RPE(30 frames) {rt30 * 100:.2f} cm {rr30:.2f} deg")
    print(f"  best wall {best / n * 1000:.1f} ms/frame ({n / best:.1f} fps) | final BA {s.final_ba_s:.2f} s | tracking "
          f"{s.track_s / n * 1000:.1f} ms/frame, keyframe work {s.mapping_s / n * 1000:.1f} ms/frame")


if __name__ == "__main__":
    main()
