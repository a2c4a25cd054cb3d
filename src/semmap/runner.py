"""One sequence run from a ``RunConfig`` alone: the segmenter, instance source and simulator ground truth it names,
then the pipeline. ``semmap run`` and every task of ``semmap batch`` go through :func:`run_config`, so a batch's
outputs are those of separate runs."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path

from semmap.config import RunConfig
from semmap.factories import instance_source_for, segmenter_for
from semmap.pipeline import Pipeline, RunResult

Progress = Callable[[Iterator, int], Iterator]


def simulated_ground_truth(dataset: Path):
    """3D ground truth for a folder written by ``semmap simulate`` (None for other datasets)."""
    dataset = Path(dataset)
    if not (dataset / "scene.json").is_file():
        return None
    from semmap.datasets.simulated import scene_of_folder
    from semmap.sim.ground_truth import gt_voxels

    scene = scene_of_folder(dataset)
    if scene is None:
        return None

    def ground_truth(res: float):
        gt = gt_voxels(scene, res)
        return gt.keys, gt.class_ids

    return ground_truth


def run_config(config: RunConfig, *, progress: Progress | None = None, track_progress: Progress | None = None,
               title: str = "semmap run", checkpoint_every: int = 0, resume: bool = False) -> RunResult:
    """Map ``config.input.dataset`` into ``config.output.out`` exactly as ``semmap run`` does (``checkpoint_every``
    frames a checkpoint; ``resume`` continues from the last one)."""
    segmenter = segmenter_for(config)
    return Pipeline(config, segmenter=segmenter, progress=progress, track_progress=track_progress,
                    ground_truth=simulated_ground_truth(config.input.dataset), title=title,
                    instances=instance_source_for(config, segmenter), checkpoint_every=checkpoint_every,
                    resume=resume).run()
