"""Runs from a configuration alone: the segmenter, instance source and ground truth a ``RunConfig`` names, then the
pipeline. ``semmap run``, ``semmap demo`` and every task of ``semmap batch`` go through :func:`run_config`, so a
batch's outputs are those of separate runs and the demo's those of ``semmap run`` on the same frames;
:func:`track_sequence` is ``semmap track``."""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from pathlib import Path

from semmap.config import InputConfig, MappingConfig, OutputConfig, RunConfig, SemanticsConfig, SemanticSource
from semmap.datasets import Dataset
from semmap.errors import ConfigError
from semmap.eval.run_report import GroundTruthFn
from semmap.factories import instance_source_for, segmenter_for
from semmap.files.parse import json_safe
from semmap.limits import check
from semmap.pipeline import Pipeline, RunResult
from semmap.poses.base import Progress
from semmap.run.paths import check_run_paths
from semmap.run.real_default import with_real_default
from semmap.types import Trajectory

log = logging.getLogger("semmap")


def simulated_ground_truth(dataset: Path | Dataset) -> GroundTruthFn | None:
    """3D ground truth of a simulated sequence: a folder written by ``semmap simulate`` or the simulator's own
    dataset (None for other datasets)."""
    from semmap.datasets.simulated import SimulatedDataset, scene_of_folder
    from semmap.sim.ground_truth import gt_voxels

    if isinstance(dataset, SimulatedDataset):
        scene = dataset.scene
    elif isinstance(dataset, Path | str) and (Path(dataset) / "scene.json").is_file():
        scene = scene_of_folder(Path(dataset))
    else:
        return None
    if scene is None:
        return None
    to_dataset_classes = _label_space_of(dataset)

    def ground_truth(res: float):
        gt = gt_voxels(scene, res)
        return gt.keys, gt.class_ids if to_dataset_classes is None else to_dataset_classes[gt.class_ids]

    return ground_truth


def _label_space_of(dataset: Path | Dataset):
    """The simulator-class -> dataset-class table of a simulated folder written in another label space (ScanNet's
    NYU-40), or None when its labels are the simulator's own."""
    import json

    from semmap.labels import simulator_to_nyu40

    if not isinstance(dataset, Path | str):
        return None
    try:
        info = json.loads((Path(dataset) / "scene.json").read_text())
    except (OSError, ValueError):
        return None
    return simulator_to_nyu40() if isinstance(info, dict) and info.get("label_space") == "nyu40" else None


def run_config(config: RunConfig, *, dataset: Dataset | None = None, progress: Progress | None = None,
               track_progress: Progress | None = None, title: str = "semmap run", checkpoint_every: int = 0,
               resume: bool = False, continue_from: Path | None = None) -> RunResult:
    """Map ``config.input.dataset`` (or an already open ``dataset``, e.g. the simulator's) into
    ``config.output.out`` exactly as ``semmap run`` does (``checkpoint_every`` frames a checkpoint; ``resume``
    continues from the last one; ``continue_from``: a finished run's folder or map file whose maps this run goes on
    from, in its frame). The outputs are checked against the inputs before anything is loaded."""
    check("every", checkpoint_every, "--checkpoint-every")
    check_run_paths(config)
    prior = None
    if continue_from is not None:
        from semmap.run.continuation import open_prior

        prior = open_prior(continue_from, config, checkpoint_every=checkpoint_every, resume=resume)
    config = with_real_default(config, dataset)
    segmenter = segmenter_for(config, dataset)
    return Pipeline(config, segmenter=segmenter, dataset=dataset, progress=progress, track_progress=track_progress,
                    ground_truth=simulated_ground_truth(dataset if dataset is not None else config.input.dataset),
                    title=title, instances=instance_source_for(config, segmenter, dataset),
                    checkpoint_every=checkpoint_every, resume=resume, prior=prior).run()


def demo_config(*, out: Path, frames: int = 300, resolution: float | None = None, scene_seed: int = 0,
                rerun: Path | None = None, oracle: bool = False, trust_weights: bool = False, cloud: bool = False
                ) -> tuple[RunConfig, Dataset]:
    """The demo's run: the default simulated scene, ground-truth poses, and the shipped network (ONNX Runtime;
    ``trust_weights``: even if its sha256 differs from the manifest) or, with ``oracle`` or without shipped
    weights (warned), the cnn-like oracle segmenter; ``cloud``: also the dense cloud (``cloud.ply``)."""
    from semmap.datasets.simulated import SimulatedDataset
    from semmap.perception.registry import demo_network

    dataset = SimulatedDataset.default(scene_seed=scene_seed, frames=frames)
    network = None if oracle else demo_network()
    if network is None and not oracle:
        log.warning("no shipped network weights (weights/manifest.json); the demo uses the oracle segmenter")
    semantics = (SemanticsConfig(segmenter=network, backend="onnx", trust_weights=trust_weights)
                 if network is not None else SemanticsConfig(source=SemanticSource.ORACLE, seed=scene_seed))
    mapping = MappingConfig() if resolution is None else MappingConfig(resolution=resolution)
    config = RunConfig(input=InputConfig(dataset=Path(dataset.name)), mapping=mapping, semantics=semantics,
                       output=OutputConfig(out=out, rerun=rerun, cloud=cloud))
    return config, dataset


def run_demo(*, out: Path, frames: int = 300, resolution: float | None = None, scene_seed: int = 0,
             rerun: Path | None = None, oracle: bool = False, trust_weights: bool = False, cloud: bool = False,
             progress: Progress | None = None) -> RunResult:
    """``semmap demo``: simulate the default scene and map it as ``semmap run`` would, scored against the
    simulator's ground truth (``out`` and ``rerun`` checked before the scene is built)."""
    from semmap.files.outputs import OutputKind, check_outputs

    check("frames", frames, "--frames")
    check("seed", scene_seed, "--scene-seed")
    check_outputs([("--out", out, OutputKind.FOLDER), ("--rerun", rerun, OutputKind.FILE)], [])
    config, dataset = demo_config(out=out, frames=frames, resolution=resolution, scene_seed=scene_seed,
                                  rerun=rerun, oracle=oracle, trust_weights=trust_weights, cloud=cloud)
    from semmap.perception.registry import SegmenterName

    segmenter = SegmenterName(config.semantics.segmenter or SegmenterName.ORACLE)
    return run_config(config, dataset=dataset, progress=progress,
                      title=f"semmap demo: {dataset.name} ({segmenter.value}, realism {dataset.realism})")


@dataclass
class TrackResult:
    """A trajectory estimated by ``semmap track``, the frames read, the seconds taken and the frames' own
    ground truth (empty when the dataset has none)."""

    estimate: Trajectory
    ground_truth: Trajectory
    frames: int
    seconds: float


def track_sequence(dataset: Dataset, method: str, *, progress: Progress | None = None) -> TrackResult:
    """Estimate the camera trajectory of ``dataset`` with tracker ``method``, keeping the frames' ground truth
    (read on the way, not in a second pass) to score the estimate."""
    from semmap.poses.base import estimate_trajectory
    from semmap.poses.file import GroundTruthRecorder
    from semmap.poses.track import make_tracker

    seen, truth = [0], GroundTruthRecorder()

    def frames():
        for frame in truth.watch(dataset):
            seen[0] += 1
            yield frame

    t0 = time.perf_counter()
    est = estimate_trajectory(make_tracker(method), frames(), total=len(dataset), progress=progress)
    return TrackResult(est, truth.trajectory(), seen[0], time.perf_counter() - t0)


def track_to_file(path: Path, method: str, out: Path, *, plot: Path | None = None, format: str = "auto",
                  stride: int = 1, max_frames: int | None = None, progress: Progress | None = None) -> dict:
    """``semmap track``: the outputs checked against the sequence first, then the trajectory tracked, written to
    ``out`` (TUM format, atomically) and summarised (scored and plotted with ground truth)."""
    from semmap.datasets import open_dataset
    from semmap.files.outputs import OutputKind, check_outputs
    from semmap.io.trajectory import write_trajectory

    check_outputs([("--out", out, OutputKind.FILE), ("--plot", plot, OutputKind.FILE)], [("DATASET", path)])
    dataset = open_dataset(path, format, stride=stride, max_frames=max_frames)
    result = track_sequence(dataset, method, progress=progress)
    write_trajectory(out, result.estimate)
    return track_summary(result, method, out, plot=plot)


def track_summary(result: TrackResult, method: str, out: Path, *, plot: Path | None = None) -> dict:
    """``semmap track``'s summary: frames, tracked, cost and, with ground truth, ATE/RPE (and the plot)."""
    from semmap.eval.trajectory import evaluate_trajectory, plot_trajectories

    summary = {"method": method, "frames": result.frames, "tracked": len(result.estimate),
               "ms_per_frame": round(1e3 * result.seconds / max(result.frames, 1), 1), "trajectory": str(out)}
    gt, est = result.ground_truth, result.estimate
    if len(gt) >= 3 and len(est) >= 3:
        scores = evaluate_trajectory(gt, est)
        summary.update({k: scores[k] for k in ("ate_rmse_m", "rpe_trans_m", "sim3_scale", "matched",
                                               "alignment_not_possible") if k in scores})
        if plot is not None:
            plot_trajectories(plot, gt, {method: est})
    elif plot is not None:
        plot_trajectories(plot, est, {})
    return json_safe(summary)


def reference_trajectory(path: Path) -> Trajectory:
    """A TUM trajectory file (read strictly), or the ground-truth poses of a dataset folder."""
    if path.is_dir():
        from semmap.datasets import open_dataset
        from semmap.poses.file import trajectory_of_dataset

        trajectory = trajectory_of_dataset(open_dataset(path))
        if not len(trajectory):
            raise ConfigError(f"{path}: the dataset folder has no ground-truth poses to score against (a TUM "
                              "groundtruth.txt, 7-Scenes frame-*.pose.txt or a simulated sequence's poses)")
        return trajectory
    from semmap.io.trajectory import read_trajectory

    return read_trajectory(path, strict=True)


def named_trajectories(paths: list[Path]) -> dict[str, Trajectory]:
    """TUM trajectory files by file stem (the parent folder's name is added where stems repeat)."""
    from semmap.io.trajectory import read_trajectory

    stems = [p.stem for p in paths]
    names = [f"{p.parent.name}/{p.stem}" if stems.count(p.stem) > 1 else p.stem for p in paths]
    if len(set(names)) < len(names):
        raise ConfigError(f"the same trajectory is given twice: {', '.join(map(str, paths))}")
    return {name: read_trajectory(p, strict=True) for name, p in zip(names, paths, strict=True)}


def evaluate_trajectories(gt: Path, est: list[Path], *, max_time_diff: float = 0.02, pairwise: bool = False,
                          reference2: Path | None = None, rotation_frames: int | None = None,
                          plot: Path | None = None, plot_errors: Path | None = None) -> dict:
    """``semmap eval-traj``: ATE / RPE of the estimates against ``gt`` (a TUM file or a dataset folder), a
    comparison of all of them with several estimates, ``pairwise`` or ``reference2``; optional plots."""
    from semmap.eval.trajectory import (
        compare_trajectories,
        evaluate_trajectory,
        on_common_frames,
        plot_position_errors,
        plot_trajectories,
    )
    from semmap.files.outputs import OutputKind, check_outputs

    check("time_diff", max_time_diff, "--max-time-diff")
    check("rotation_frames", rotation_frames, "--rotation-frames")
    check_outputs([("--plot", plot, OutputKind.FILE), ("--plot-errors", plot_errors, OutputKind.FILE)],
                  [("GT", gt), *(("EST", p) for p in est), ("--reference2", reference2)])
    reference = reference_trajectory(gt)
    estimates = named_trajectories(est)
    if len(estimates) == 1 and not (pairwise or reference2 or rotation_frames):
        try:
            scores = evaluate_trajectory(reference, next(iter(estimates.values())), max_time_diff=max_time_diff)
        except ConfigError as exc:
            raise ConfigError(f"{est[0]} against {gt}: {exc}") from None
    else:
        scores = compare_trajectories(reference, estimates, pairwise=pairwise, rotation_frames=rotation_frames,
                                      reference2=None if reference2 is None else reference_trajectory(reference2),
                                      max_time_diff=max_time_diff)
    if plot is not None:
        plot_trajectories(plot, reference, estimates, max_time_diff=max_time_diff)
    if plot_errors is not None:
        ref, common = on_common_frames(reference, estimates, max_time_diff=max_time_diff)
        plot_position_errors(plot_errors, ref, common, title=f"position error against {gt.name}, SE(3) aligned")
    return json_safe(scores)
