"""Camera tracking accuracy and speed: semmap's trackers against Open3D's RGB-D odometry, in one run.

Sequences: the real 7-Scenes redkitchen frames in ../shared/data (600; skipped with a message when absent)
and simulated sequences (desk and walk 200 frames, loop 450 frames: the 1.25 laps that bring the camera back
over its start; orbit on request). Methods:
semmap-slam (dense odometry + ORB loop closure + pose graph, the default of ``--poses slam``),
semmap-slam-noloop (the same without loop closure), semmap-slam-orb (the ORB-SLAM2-style feature SLAM with dense
refinement), semmap-slam-features (the feature SLAM alone), semmap-odometry (dense keyframe odometry) and the
peers open3d-f2f (legacy hybrid odometry, frame to frame) and open3d-f2f-tensor (tensor hybrid, frame to
frame). Frames are loaded into memory before timing, so ms/frame measures tracking only (the final
``trajectory()`` call, e.g. SLAM's global optimisation, is included). Every method sees the same frames (7-Scenes
colour registered onto depth, as ``semmap run`` reads it). Simulated sequences are rendered with the
``--realism`` preset (default ``kinect``: structured-light depth, a real colour camera, hand-held motion;
``clean`` for today's exact frames); every row names it (7-Scenes rows: ``real``).
Prints one JSON line per sequence and method, then a table with the ATE ratio against open3d-f2f, then all rows
again as one JSON line (``tracking-summary``).

    python benchmarks/bench_tracking.py [--quick] [--sequences 7scenes-redkitchen,sim-desk] [--methods ...]
                                        [--frames N] [--out DIR] [--realism clean|kinect|hard]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from semmap.datasets import open_dataset
from semmap.datasets.simulated import SimulatedDataset
from semmap.errors import SemmapError
from semmap.eval.trajectory import evaluate_trajectory, plot_trajectories
from semmap.io.trajectory import write_trajectory
from semmap.poses.file import trajectory_of_dataset
from semmap.poses.track import make_tracker
from semmap.sim.realism import REALISMS
from semmap.types import Frame, Trajectory

SEVEN_SCENES = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "7scenes-redkitchen"
#: Simulated sequences: name -> (scene seed, trajectory kind, frames).
SIM_SEQUENCES = {"sim-desk": (0, "desk", 200), "sim-loop": (1, "loop", 450), "sim-orbit": (2, "orbit", 200),
                 "sim-walk": (3, "walk", 200)}
ALL_SEQUENCES = ("7scenes-redkitchen", *SIM_SEQUENCES)
DEFAULT_SEQUENCES = ("7scenes-redkitchen", "sim-desk", "sim-loop", "sim-walk")
QUICK_SEQUENCES = ("7scenes-redkitchen", "sim-desk", "sim-loop")
#: Benchmark method name -> tracker name for :func:`semmap.poses.track.make_tracker`.
METHODS = {"semmap-slam": "slam", "semmap-slam-noloop": "slam-noloop", "semmap-slam-orb": "slam-orb",
           "semmap-slam-features": "slam-features", "semmap-odometry": "odometry",
           "open3d-f2f": "open3d-f2f", "open3d-f2f-tensor": "open3d-f2f-tensor"}
PEER = "open3d-f2f"
#: the simulator's preset these benchmarks use by default (issue 34: what real sensors and hands look like)
DEFAULT_REALISM = "kinect"


def load_sequence(name: str, frames: int, realism: str = DEFAULT_REALISM) -> list[Frame] | None:
    """Up to ``frames`` frames of a sequence (simulated ones with the ``realism`` preset), in memory; None (with a
    message) when it is not available."""
    if name == "7scenes-redkitchen":
        if not SEVEN_SCENES.is_dir():
            print(f"skipping {name}: {SEVEN_SCENES} is not present", file=sys.stderr)
            return None
        # registered colour only: the colour camera's own image is for segmentation (and would double the memory)
        return [f.with_(raw_color=None) for f in open_dataset(SEVEN_SCENES, max_frames=frames)]
    seed, kind, _ = SIM_SEQUENCES[name]
    return list(SimulatedDataset.default(scene_seed=seed, trajectory=kind, frames=frames,
                                        realism=realism))


def slam_available() -> str:
    """"" when semmap.poses.slam imports, else why not."""
    try:
        import semmap.poses.slam as slam

        slam.RgbdSlam, slam.SlamConfig  # noqa: B018 - both names must exist
    except (ImportError, AttributeError) as exc:
        return str(exc)
    return ""


def run_method(method: str, frames: list[Frame]) -> tuple[Trajectory, float, object]:
    """(estimated trajectory, ms per frame, tracker) of one method over in-memory frames."""
    tracker = make_tracker(METHODS[method])
    start = time.perf_counter()
    for frame in frames:
        tracker.track(frame)
    trajectory = tracker.trajectory()
    return trajectory, 1000 * (time.perf_counter() - start) / len(frames), tracker


def _extra(tracker: object) -> dict:
    """Tracker-specific counts worth printing (motion-model fallbacks, failed steps)."""
    stats = getattr(tracker, "stats", None)
    if hasattr(tracker, "fallbacks"):
        extra = {"fallbacks": len(tracker.fallbacks), "keyframes": sum(1 for r in tracker.reports if r.keyframe)}
        if stats is not None and hasattr(stats, "relocalisations"):
            extra |= {"loops": stats.loops, "relocalisations": stats.relocalisations}
        return extra
    if stats is not None and hasattr(stats, "dense_fallbacks"):
        return {"lost": stats.lost, "keyframes": stats.keyframes, "loops": stats.loops,
                "dense_fallbacks": stats.dense_fallbacks, "dense_refined": stats.dense_refined}
    if hasattr(tracker, "failures") and isinstance(tracker.failures, int):
        return {"failures": tracker.failures}
    return {}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="150 real frames, 100 per simulated sequence, 2 sims")
    parser.add_argument("--sequences", help=f"comma-separated subset of {', '.join(ALL_SEQUENCES)} "
                                            f"(default: all but sim-orbit)")
    parser.add_argument("--methods", help=f"comma-separated subset of {', '.join(METHODS)}")
    parser.add_argument("--frames", type=int, help="frames per sequence (default 600 real, 200 or 450 simulated)")
    parser.add_argument("--realism", default=DEFAULT_REALISM, choices=REALISMS,
                        help="the simulator's preset for sim-* sequences (default kinect)")
    parser.add_argument("--out", type=Path, help="write trajectories (TUM) and a plot per sequence here")
    args = parser.parse_args()

    sequences = args.sequences.split(",") if args.sequences else list(QUICK_SEQUENCES if args.quick
                                                                         else DEFAULT_SEQUENCES)
    methods = args.methods.split(",") if args.methods else list(METHODS)
    for what, chosen, known in (("sequence", sequences, ALL_SEQUENCES), ("method", methods, METHODS)):
        unknown = [c for c in chosen if c not in known]
        if unknown:
            parser.error(f"unknown {what} {', '.join(unknown)}; known: {', '.join(known)}")
    why = slam_available()
    if why and any(m.startswith("semmap-slam") for m in methods):
        print(f"skipping semmap-slam*: semmap.poses.slam is not importable yet ({why})", file=sys.stderr)
        methods = [m for m in methods if not m.startswith("semmap-slam")]

    rows = []
    for sequence in sequences:
        real = sequence.startswith("7scenes")
        n = args.frames or ((150 if real else 100) if args.quick else (600 if real else SIM_SEQUENCES[sequence][2]))
        frames = load_sequence(sequence, n, args.realism)
        if frames is None:
            continue
        gt = trajectory_of_dataset(frames)
        estimates = {}
        for method in methods:
            try:
                est, ms, tracker = run_method(method, frames)
                metrics = evaluate_trajectory(gt, est)
            except SemmapError as exc:
                print(f"{sequence} / {method}: failed: {exc}", file=sys.stderr)
                continue
            estimates[method] = est
            row = {"bench": "tracking", "sequence": sequence, "method": method, "frames": len(frames),
                   "realism": "real" if real else args.realism,
                   "ate_rmse_m": round(metrics["ate_rmse_m"], 5), "rpe_trans_m": round(metrics["rpe_trans_m"], 5),
                   "ms_per_frame": round(ms, 1), "rpe_rot_deg": round(metrics["rpe_rot_deg"], 4),
                   "ate_max_m": round(metrics["ate_max_m"], 5),
                   "sim3_scale": round(metrics["sim3_scale"], 4), "ate_sim3_m": round(metrics["ate_sim3_rmse_m"], 5),
                   "tracked": len(est), "matched": metrics["matched"],
                   **_extra(tracker)}
            rows.append(row)
            print(json.dumps(row), flush=True)
        if args.out:
            _write_outputs(args.out, sequence, gt, estimates)
    print_table(rows)
    print(json.dumps({"bench": "tracking-summary", "peer": PEER, "realism": args.realism, "results": rows}))


def _write_outputs(out: Path, sequence: str, gt: Trajectory, estimates: dict[str, Trajectory]) -> None:
    """Ground truth, each estimate (TUM files) and one plot for a sequence."""
    folder = out / sequence
    write_trajectory(folder / "groundtruth.txt", gt)
    for method, est in estimates.items():
        write_trajectory(folder / f"{method}.txt", est)
    plot_trajectories(out / f"{sequence}.png", gt, estimates, title=f"{sequence}: {len(gt)} frames")


def print_table(rows: list[dict]) -> None:
    """Human-readable summary; the ratio is ATE / ATE(open3d-f2f) on the same sequence (lower is better), and
    ``matched`` the poses scored (fewer than ``frames`` when a tracker lost frames: its ATE covers only those)."""
    if not rows:
        return
    peer = {r["sequence"]: r["ate_rmse_m"] for r in rows if r["method"] == PEER}
    print(f"\n{'sequence':<20} {'method':<20} {'frames':>6} {'ATE cm':>8} {'RPE cm':>8} {'RPE deg':>8} "
          f"{'ms/frame':>9} {'ATE/' + PEER:>15} {'matched':>8}")
    for r in rows:
        base = peer.get(r["sequence"])
        ratio = f"{r['ate_rmse_m'] / base:.2f}" if base else "-"
        print(f"{r['sequence']:<20} {r['method']:<20} {r['frames']:>6} {100 * r['ate_rmse_m']:>8.2f} "
              f"{100 * r['rpe_trans_m']:>8.2f} {r['rpe_rot_deg']:>8.3f} {r['ms_per_frame']:>9.1f} {ratio:>15} "
              f"{r['matched']:>8}")


if __name__ == "__main__":
    main()
