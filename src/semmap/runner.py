"""One sequence run from a ``RunConfig`` alone: the segmenter, instance source and simulator ground truth it names,
then the pipeline. ``semmap run`` and every task of ``semmap batch`` go through :func:`run_config`, so a batch's
outputs are those of separate runs."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path

from semmap.config import LoopMode, RunConfig, SemanticSource
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


def segmenter_for(config: RunConfig):
    """The segmenter the configuration names (``--segmenter``, or ``--semantics oracle``), or None."""
    from semmap.perception.registry import make_segmenter

    s = config.semantics
    name = s.segmenter or ("oracle" if s.source == SemanticSource.ORACLE else None)
    if name is None:
        return None
    label_set = None
    if name == "oracle":
        from semmap.datasets import open_dataset

        label_set = open_dataset(config.input.dataset, config.input.format, max_frames=1,
                                 ros=config.input.ros.options()).label_set
    # online, the network has one core to itself beside tracking and mapping (its own threads would fight theirs)
    threads = config.online.segment_threads if config.mode == LoopMode.ONLINE else None
    return make_segmenter(name, weights=s.weights, label_set=label_set, k=s.k, label_confidence=s.label_confidence,
                          oracle_preset=s.oracle_preset, seed=s.seed, backend=s.backend, batch_size=s.batch_size,
                          input_size=s.input_size, threads=threads)


def instance_source_for(config: RunConfig, segmenter):
    """The instance source ``--instances`` names (None without it)."""
    o = config.objects
    if o.instances is None:
        return None
    from semmap.perception.instances import make_instance_source

    label_set = None
    if segmenter is None:
        from semmap.datasets import open_dataset

        c = config.input
        label_set = open_dataset(c.dataset, c.format, labels=c.labels, max_frames=1, ros=c.ros.options()).label_set
    return make_instance_source(o.instances, label_set=label_set, segmenter=segmenter, weights=o.weights,
                                preset=o.errors, seed=o.seed)


def run_config(config: RunConfig, *, progress: Progress | None = None, track_progress: Progress | None = None,
               title: str = "semmap run", checkpoint_every: int = 0, resume: bool = False) -> RunResult:
    """Map ``config.input.dataset`` into ``config.output.out`` exactly as ``semmap run`` does (``checkpoint_every``
    frames a checkpoint; ``resume`` continues from the last one)."""
    segmenter = segmenter_for(config)
    return Pipeline(config, segmenter=segmenter, progress=progress, track_progress=track_progress,
                    ground_truth=simulated_ground_truth(config.input.dataset), title=title,
                    instances=instance_source_for(config, segmenter), checkpoint_every=checkpoint_every,
                    resume=resume).run()
