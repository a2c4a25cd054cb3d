"""(issue 34) Where a tracking run's error accumulates along the path: ``bench_tracking.py``'s sequence and
tracker, per frame and per keyframe step against the ground truth.

    python scripts/research/walk_drift_check.py --sequence sim-walk --frames 600 --save /tmp/walk600.npz
    python scripts/research/walk_drift_check.py --load /tmp/walk600.npz          # the analysis again, no run

A run records, per frame: the ground truth, the tracker's final (pose-graph) pose and its raw odometry pose (the
chain before any optimisation), the keyframe it was aligned to, the alignment's fitness and fallback, and what the
frame offered (valid depth within the odometry's range, median depth, image gradient, the share of wall, floor
and ceiling pixels where the frame has labels); per keyframe its ORB keypoints with depth; every loop-closure and
relocalisation attempt with its outcome. The report then gives the ATE along the path, the raw chain's drift
(frame 0 aligned, no fit), the keyframe steps whose rotation error is largest (a rotation error tilts all the
path after it: lever arm = the distance the camera travels afterwards), and what those steps looked like against
the median step; and the path's length, turning and revisits (:func:`path_stats`), the statistics to compare a
simulated walk with the 7-Scenes frames.
"""

from __future__ import annotations

import argparse
import io
import itertools
import json
import logging
import sys
import time
from pathlib import Path

import numpy as np

from semmap.eval.trajectory import evaluate_trajectory
from semmap.files.atomic import write_bytes_atomic
from semmap.labels import INDOOR_LABELS
from semmap.poses.dense_align import grey
from semmap.poses.file import trajectory_of_dataset
from semmap.types import Frame, Trajectory, invert_pose, rotation_angle

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
import bench_tracking  # the benchmark's sequences, tracker names and runner, not a copy

#: labels of views without structure to align on (a frame mostly of these is "bare")
STUFF = tuple(INDOOR_LABELS.id_of(n) for n in ("wall", "floor", "ceiling"))


def frame_stats(frame: Frame, depth_max: float) -> tuple[float, float, float, float]:
    """(valid depth share within (0, depth_max], median valid depth m, mean |grey gradient|, wall/floor/ceiling
    share of labelled pixels or NaN): what a frame offers an aligner."""
    d = frame.depth
    valid = (d > 0) & (d <= depth_max)
    g = grey(frame.rgb).astype(np.float32)
    gradient = float(np.abs(np.diff(g, axis=1)).mean() + np.abs(np.diff(g, axis=0)).mean())
    stuff = float("nan")
    if frame.labels is not None and (frame.labels > 0).any():
        stuff = float(np.isin(frame.labels, STUFF).sum() / (frame.labels > 0).sum())
    return float(valid.mean()), float(np.median(d[valid])) if valid.any() else 0.0, gradient, stuff


def _instrument(tracker) -> list[dict]:
    """Record every PnP + dense registration the SLAM tries (loops and relocalisations) with its outcome."""
    attempts: list[dict] = []
    register = tracker._register

    def recorded(feats, image, k):
        found = register(feats, image, k)
        attempts.append({"frame": len(tracker._poses), "keyframe": int(k), "frame_of_keyframe":
                         int(tracker.keyframes[k].frame), "ok": found is not None})
        return found

    tracker._register = recorded
    return attempts


def record(sequence: str, frames_n: int, realism: str, method: str) -> dict:
    """Run ``method`` over the sequence and return every per-frame and per-keyframe array the report needs."""
    frames = bench_tracking.load_sequence(sequence, frames_n, realism)
    if frames is None:
        raise SystemExit(f"{sequence} is not available")
    tracker = bench_tracking.make_tracker(bench_tracking.METHODS[method])
    attempts = _instrument(tracker) if hasattr(tracker, "_register") else []
    depth_max = tracker.config.depth_max if hasattr(tracker, "config") else 4.0
    stats = np.array([frame_stats(f, depth_max) for f in frames])
    start = time.perf_counter()
    for f in frames:
        tracker.track(f)
    est = tracker.trajectory()
    seconds = time.perf_counter() - start
    gt = trajectory_of_dataset(frames)
    kfs = getattr(tracker, "keyframes", [])
    return {
        "sequence": sequence, "method": method, "realism": realism, "seconds": seconds,
        "stamps": est.timestamps, "est": est.poses, "gt": gt.poses, "gt_stamps": gt.timestamps,
        "raw": np.asarray(tracker._poses), "kf_of_frame": np.asarray(getattr(tracker, "_kf_of_frame", [])),
        "kf_frame": np.array([kf.frame for kf in kfs]), "kf_parent": np.array([kf.parent for kf in kfs]),
        "kf_keypoints": np.array([int(kf.feats.has_depth.sum()) for kf in kfs]),
        "fitness": np.array([r.fitness for r in tracker.reports]),
        "fallback": np.array([bool(r.fallback) for r in tracker.reports]),
        "keyframe": np.array([r.keyframe for r in tracker.reports]),
        "loop_frames": np.asarray(getattr(getattr(tracker, "stats", None), "loop_frames", []), int),
        "attempts": json.dumps(attempts), "frame_stats": stats,
    }


def save(path: Path, run: dict) -> None:
    """The recorded run as one .npz (atomic write)."""
    buf = io.BytesIO()
    np.savez_compressed(buf, **{k: np.asarray(v) for k, v in run.items()})
    write_bytes_atomic(path, buf.getvalue())


def load(path: Path) -> dict:
    """A run saved by :func:`save`."""
    with np.load(path, allow_pickle=False) as d:
        run = {k: d[k] for k in d.files}
    for k in ("sequence", "method", "realism", "attempts", "seconds"):
        run[k] = run[k].item()
    return run


def aligned_errors(gt: np.ndarray, est: np.ndarray) -> np.ndarray:
    """Per-frame position error (m) of ``est`` after the SE(3) Umeyama fit of its positions onto ``gt``'s."""
    a, b = est[:, :3, 3], gt[:, :3, 3]
    ma, mb = a.mean(0), b.mean(0)
    u, _, vt = np.linalg.svd((b - mb).T @ (a - ma))
    s = np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))])
    R = u @ s @ vt
    return np.linalg.norm((a - ma) @ R.T + mb - b, axis=1)


def anchored_drift(gt: np.ndarray, est: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(position error m, rotation error deg) per frame of ``est`` moved so that its first pose is ``gt``'s: the
    drift as the chain accumulates it, without a fit spreading it over the path."""
    moved = gt[0] @ invert_pose(est[0]) @ est
    pos = np.linalg.norm(moved[:, :3, 3] - gt[:, :3, 3], axis=1)
    rot = np.degrees([rotation_angle(g[:3, :3].T @ m[:3, :3]) for g, m in zip(gt, moved, strict=True)])
    return pos, np.asarray(rot)


def relative_error(gt: np.ndarray, est: np.ndarray, i: int, j: int) -> tuple[float, float]:
    """(translation m, rotation deg) error of ``est``'s motion from frame i to j against ``gt``'s."""
    E = invert_pose(invert_pose(gt[i]) @ gt[j]) @ (invert_pose(est[i]) @ est[j])
    return float(np.linalg.norm(E[:3, 3])), float(np.degrees(rotation_angle(E[:3, :3])))


def path_stats(gt: np.ndarray, radius: float = 0.5, angle_deg: float = 45.0, gap_s: float = 5.0,
               fps: float = 30.0) -> dict:
    """Path length, total turning, extent, and revisits: the share of frames with an earlier frame at least
    ``gap_s`` before within ``radius`` metres and ``angle_deg`` of viewing direction (a place seen again)."""
    p = gt[:, :3, 3]
    steps = np.linalg.norm(np.diff(p, axis=0), axis=1)
    turn = [rotation_angle(a[:3, :3].T @ b[:3, :3]) for a, b in itertools.pairwise(gt)]
    z = gt[:, :3, 2]
    gap = int(gap_s * fps)
    revisit = np.zeros(len(gt), bool)
    for i in range(gap, len(gt)):
        near = np.linalg.norm(p[: i - gap] - p[i], axis=1) < radius
        same_view = z[: i - gap] @ z[i] > np.cos(np.radians(angle_deg))
        revisit[i] = bool((near & same_view).any())
    hull = p.max(0) - p.min(0)
    return {"frames": len(gt), "path_m": round(float(steps.sum()), 3), "turn_deg": round(float(np.degrees(
        np.sum(turn))), 1), "extent_m": [round(float(x), 2) for x in hull],
        "max_from_start_m": round(float(np.linalg.norm(p - p[0], axis=1).max()), 2),
        "revisit_share": round(float(revisit.mean()), 3), "first_revisit": int(np.argmax(revisit)) if
        revisit.any() else -1}


def keyframe_steps(run: dict) -> list[dict]:
    """One row per odometry step between consecutive keyframes: its raw rotation / translation error against the
    ground truth, the lever arm (path travelled after it), and what the frames between offered."""
    gt, raw, kf = run["gt"], run["raw"], run["kf_frame"]
    p = gt[:, :3, 3]
    after = np.concatenate([np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1)[::-1])[::-1], [0.0]])
    st = run["frame_stats"]
    rows = []
    for k in range(1, len(kf)):
        i, j = int(kf[k - 1]), int(kf[k])
        if run["kf_parent"][k] != k - 1:
            continue  # a relocalised keyframe hangs off another one
        dt, dr = relative_error(gt, raw, i, j)
        gdist = float(np.linalg.norm(p[j] - p[i]))
        gang = float(np.degrees(rotation_angle(gt[i][:3, :3].T @ gt[j][:3, :3])))
        rows.append({"k": k, "from": i, "to": j, "err_mm": 1000 * dt, "err_deg": dr, "lever_m": float(after[j]),
                     "moved_m": gdist, "turned_deg": gang, "fitness": float(run["fitness"][i + 1: j + 1].min()),
                     "fallbacks": int(run["fallback"][i + 1: j + 1].sum()),
                     "depth_valid": float(st[i: j + 1, 0].min()), "depth_median_m": float(st[i: j + 1, 1].max()),
                     "gradient": float(st[i: j + 1, 2].min()), "stuff": float(np.nanmax(st[i: j + 1, 3]))
                     if np.isfinite(st[i: j + 1, 3]).any() else float("nan"),
                     "keypoints": int(run["kf_keypoints"][k])})
    return rows


def stretches(err: np.ndarray, window: int) -> list[tuple[int, int, float]]:
    """(start, end, rise in metres) of the ``window``-frame stretches where ``err`` rises most (non-overlapping)."""
    rise = err[window:] - err[:-window]
    order = np.argsort(-rise)
    taken: list[tuple[int, int, float]] = []
    for s in order:
        if all(abs(int(s) - t[0]) >= window for t in taken):
            taken.append((int(s), int(s) + window, float(rise[s])))
        if len(taken) == 5:
            break
    return taken


def report(run: dict, top: int) -> None:
    """Print where the run's error comes from (see the module docstring)."""
    gt, est, raw = run["gt"], run["est"], run["raw"]
    m = evaluate_trajectory(Trajectory(run["gt_stamps"], gt, ()), Trajectory(run["stamps"], est, ()))
    print(f"{run['sequence']} / {run['method']} ({run['realism']}), {len(gt)} frames, {run['seconds']:.0f} s: "
          f"ATE {100 * m['ate_rmse_m']:.2f} cm (max {100 * m['ate_max_m']:.2f}), RPE {100 * m['rpe_trans_m']:.2f} cm "
          f"{m['rpe_rot_deg']:.3f} deg, Sim(3) scale {m['sim3_scale']:.4f}")
    ate_raw = aligned_errors(gt, raw)
    print(f"raw odometry chain (no pose graph): ATE {100 * np.sqrt((ate_raw ** 2).mean()):.2f} cm; keyframes "
          f"{len(run['kf_frame'])}, fallbacks {int(run['fallback'].sum())}, loops at frames "
          f"{run['loop_frames'].tolist()}")
    attempts = json.loads(run["attempts"])
    print(f"registrations tried {len(attempts)}, accepted {sum(a['ok'] for a in attempts)}: "
          + ", ".join(f"{a['frame']}->{a['frame_of_keyframe']}{'+' if a['ok'] else '-'}" for a in attempts))
    ate = aligned_errors(gt, est)
    pos, rot = anchored_drift(gt, raw)
    for lo in range(0, len(gt), 50):
        hi = min(len(gt), lo + 50)
        st = run["frame_stats"][lo:hi]
        stuff = np.nanmax(st[:, 3]) if np.isfinite(st[:, 3]).any() else float("nan")
        print(f"  frames {lo:3d}-{hi - 1:3d}: ATE {100 * ate[lo:hi].mean():5.2f} cm | raw drift "
              f"{100 * pos[hi - 1]:5.2f} cm {rot[hi - 1]:5.2f} deg | depth valid min {st[:, 0].min():.2f} "
              f"median depth max {st[:, 1].max():.2f} m | stuff max {stuff:.2f}")
    for s, e, r in stretches(rot, 30):
        print(f"  raw rotation drift rises {r:.2f} deg over frames {s}-{e}")
    rows = keyframe_steps(run)
    by = sorted(rows, key=lambda r: -r["err_deg"] * r["lever_m"])
    keys = ("err_deg", "err_mm", "moved_m", "turned_deg", "fitness", "depth_valid", "depth_median_m", "gradient",
            "stuff", "keypoints")
    print("keyframe steps with the largest rotation error x lever arm (frames, " + ", ".join(keys) + ", lever m)")
    for r in by[:top]:
        print(f"  {r['from']:3d}-{r['to']:3d}: " + " ".join(f"{r[k]:.3g}" for k in keys) + f" {r['lever_m']:.1f}")
    med = {k: float(np.nanmedian([r[k] for r in rows])) for k in keys}
    print("  median step: " + " ".join(f"{k}={v:.3g}" for k, v in med.items()))
    print("path:", json.dumps(path_stats(gt)))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sequence", default="sim-walk", choices=bench_tracking.ALL_SEQUENCES)
    ap.add_argument("--frames", type=int, default=600)
    ap.add_argument("--realism", default=bench_tracking.DEFAULT_REALISM)
    ap.add_argument("--method", default="semmap-slam", choices=tuple(bench_tracking.METHODS))
    ap.add_argument("--save", type=Path, help="keep the recorded run here (.npz)")
    ap.add_argument("--load", type=Path, help="analyse a saved run instead of running")
    ap.add_argument("--top", type=int, default=12, help="keyframe steps listed")
    args = ap.parse_args()
    logging.basicConfig(level=logging.WARNING)
    if args.load:
        run = load(args.load)
    else:
        run = record(args.sequence, args.frames, args.realism, args.method)
        if args.save:
            save(args.save, run)
    report(run, args.top)


if __name__ == "__main__":
    main()
