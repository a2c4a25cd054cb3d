"""Where the camera is: ``semmap track`` (a sequence's trajectory by odometry) and ``semmap localize`` (Monte-Carlo
localization in a prior map)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from semmap.cli.options import FORMATS_HELP, Json, MemoryBudget, budget
from semmap.cli.terminal import cm, interruptible, progress_bar, setup_logging, sim3_scale, summary_out
from semmap.datasets import AUTO
from semmap.errors import SemmapError
from semmap.perception.registry import SEGMENTERS
from semmap.poses.track import TRACKERS


def track(
    dataset: Annotated[Path, typer.Argument(help="RGB-D sequence folder (TUM RGB-D or 7-Scenes layout)")],
    out: Annotated[Path, typer.Option("--out", "-o", help="trajectory file to write (TUM format)")],
    method: Annotated[str, typer.Option(help=TRACKERS.choices())] = TRACKERS.names[0],
    format: Annotated[str, typer.Option(help=FORMATS_HELP)] = AUTO,
    max_frames: Annotated[int | None, typer.Option(help="use at most N frames")] = None,
    stride: Annotated[int, typer.Option(help="use every k-th frame")] = 1,
    plot: Annotated[Path | None, typer.Option(help="also plot the trajectory (and ground truth) to this PNG")] = None,
    as_json: Json = False,
) -> None:
    """Estimate the camera trajectory of a sequence and write it in TUM format; scored against the dataset's
    ground truth when it has one."""
    setup_logging(False)
    from semmap.runner import track_to_file

    with interruptible():
        summary = track_to_file(dataset, method, out, plot=plot, format=format, stride=stride,
                                max_frames=max_frames, progress=progress_bar(f"tracking ({method})"))
    rows = [("method", method), ("frames tracked", f"{summary['tracked']} of {summary['frames']}"),
            ("ms per frame", f"{summary['ms_per_frame']:.1f}"), ("trajectory", summary["trajectory"])]
    if "ate_rmse_m" in summary:
        rows += [("ATE (SE(3) aligned)", cm(summary["ate_rmse_m"])), ("RPE per frame", cm(summary["rpe_trans_m"])),
                 ("Sim(3) scale", sim3_scale(summary["sim3_scale"])), ("poses matched", str(summary["matched"]))]
    else:
        rows.append(("ATE", "not scored (the sequence has no ground truth)"))
    if plot is not None:
        rows.append(("plot", str(plot)))
    summary_out(summary, as_json, f"semmap track: {dataset}", rows)


def localize(
    map_path: Annotated[Path, typer.Argument(metavar="MAP", help="map.semmap written by semmap run (or its folder)")],
    sequence: Annotated[Path, typer.Argument(metavar="SEQ", help="RGB-D sequence to localize (TUM / 7-Scenes folder)")],
    out: Annotated[Path, typer.Option("--out", "-o", help="output folder")],
    model: Annotated[str, typer.Option(help="semantic | geometry | cosine (the paper's score)")] = "semantic",
    particles: Annotated[int, typer.Option(help="number of particles")] = 2000,
    init: Annotated[str, typer.Option(help="global (anywhere in the map) | tracking (around --init-pose or the "
                                           "first frame's ground truth)")] = "global",
    init_pose: Annotated[str | None, typer.Option(help="tracking start: 'tx ty tz qx qy qz qw'")] = None,
    mode: Annotated[str, typer.Option(help="6dof | ground (x, y, yaw; height and tilt known)")] = "6dof",
    motion: Annotated[str, typer.Option(help="odometry (semmap's dense odometry) | gt-noisy (ground truth with "
                                             "drift, experiments) | PATH of a TUM trajectory")] = "odometry",
    motion_noise: Annotated[float, typer.Option(help="gt-noisy: drift as a fraction of each motion")] = 0.05,
    segmenter: Annotated[str, typer.Option(help=f"auto (oracle when the sequence has label images) | none | "
                                                f"{SEGMENTERS.choices()}")] = "auto",
    weights: Annotated[Path | None, typer.Option(help="network weights (espnetv2) or predictions folder "
                                                 "(precomputed)")] = None,
    trust_weights: Annotated[bool, typer.Option("--trust-weights", help="use shipped weights whose sha256 differs "
                                                "from weights/manifest.json (with a warning)")] = False,
    height: Annotated[float | None, typer.Option(help="ground mode: camera height (m); default: from ground "
                                                 "truth")] = None,
    pitch_deg: Annotated[float, typer.Option(help="ground mode with --height: camera pitch (°, down < 0)")] = 0.0,
    roll_deg: Annotated[float, typer.Option(help="ground mode with --height: camera roll (°)")] = 0.0,
    points: Annotated[int, typer.Option(help="points per scan")] = 400,
    stride: Annotated[int, typer.Option(help="use every k-th frame")] = 1,
    max_frames: Annotated[int | None, typer.Option(help="use at most N frames")] = None,
    seed: Annotated[int, typer.Option(help="random seed")] = 0,
    gif: Annotated[bool, typer.Option("--gif", help="also write particles.gif")] = False,
    memory_budget: MemoryBudget = None,
    as_json: Json = False,
) -> None:
    """Monte-Carlo localization of a sequence's camera in a prior map: writes localization.txt, localization.npz,
    report.json, report.md, particles.png, errors.png (with ground truth) and optionally particles.gif."""
    setup_logging(False)
    budget(memory_budget)
    import numpy as np

    from semmap.localization.filter import FilterSettings
    from semmap.localization.motion import MotionMode
    from semmap.localization.observation import ObservationKind
    from semmap.localization.run import InitMode
    from semmap.localization.sequence import LocalizeOptions, localize_sequence
    from semmap.types import pose_from_tum

    def choice(enum, value: str, what: str):
        try:
            return enum(value)
        except ValueError:
            raise SemmapError(f"unknown {what} {value!r}; choose from {', '.join(e.value for e in enum)}") from None

    start = None
    if init_pose is not None:
        try:
            with np.errstate(invalid="ignore", divide="ignore"):  # a zero quaternion is refused below, in one line
                start = pose_from_tum([float(v) for v in init_pose.replace(",", " ").split()])
        except (ValueError, IndexError):
            raise SemmapError(f"--init-pose must be 7 numbers 'tx ty tz qx qy qz qw', got {init_pose!r}") from None
    settings = FilterSettings(particles=particles, mode=choice(MotionMode, mode, "mode"),
                              model=choice(ObservationKind, model, "model"))
    options = LocalizeOptions(settings=settings, init=choice(InitMode, init, "initialisation"), init_pose=start,
                              motion=motion, motion_noise=motion_noise, segmenter=segmenter, weights=weights,
                              trust_weights=trust_weights, height=height, pitch_deg=pitch_deg, roll_deg=roll_deg,
                              points=points, stride=stride, max_frames=max_frames, seed=seed, gif=gif)
    with interruptible():
        result, files = localize_sequence(map_path, sequence, out, options, progress=progress_bar("localizing"))
    summary = result.summary()
    summary_out({**summary, "files": sorted(files)}, as_json, f"semmap localize: {out}",
                 _localize_rows(summary, out, sorted(files)))


def _localize_rows(s: dict, out: Path, files: list[str]) -> list[tuple[str, str]]:
    """``semmap localize``'s table: the filter, whether and when it converged, the final error, the cost."""
    converged = ("no" if s["frames_to_converge"] is None else
                 f"after {s['frames_to_converge']} updates ({s['seconds_to_converge']} s)")
    rows = [("filter", f"{s['particles']:,} particles, {s['model']} model, {s['mode']}, init {s['init']}, "
                       f"motion {s['motion']}"),
            ("updates", f"{s['updates']} ({s['frames_skipped']} frames skipped)"), ("converged", converged),
            ("converged at the end", "yes" if s["converged_at_end"] else "no")]
    if "pos_err_m_final" in s:
        rows.append(("final error", f"{cm(s['pos_err_m_final'])}, {s['rot_err_deg_final']:.2f}°"))
        if "pos_err_m_after_convergence" in s:
            rows.append(("error after convergence", f"{cm(s['pos_err_m_after_convergence']['median'])}, "
                                                    f"{s['rot_err_deg_after_convergence']['median']:.2f}° (median)"))
        rows.append(("on the true pose", "yes" if s["converged_to_truth"] else "no"))
    if s["ms_per_update"]:
        rows.append(("ms per update", f"{s['ms_per_update']['median']:.1f} (median)"))
    rows.append(("outputs", f"{out}: {', '.join(Path(f).name for f in files)}"))
    return rows
