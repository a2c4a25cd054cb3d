"""A run's outputs against its inputs, before any work (:mod:`semmap.files.outputs`), and the rerun recording
inside ``--out`` written into the staging folder so that it moves into ``--out`` with the rest."""

from __future__ import annotations

import os
from pathlib import Path

from semmap.config import OutputConfig, RunConfig
from semmap.files.outputs import Named, OutputKind, check_outputs, check_utf8
from semmap.io.staged_run import check_out_dir


def run_inputs(config: RunConfig) -> list[Named]:
    """Every path a run reads, by option: the sequence, label folder, weights or predictions, a trajectory file
    given as ``--poses``, the class prior, the user's model, its sidecar and class mapping, and the instance
    weights."""
    from semmap.poses.track import POSE_SOURCES

    poses, s = config.poses.source, config.semantics
    model = Path(s.model) if s.model and Path(s.model).exists() else None  # (a hub id is no path)
    class_map = s.class_map if s.class_map is not None and s.class_map.exists() else None  # (or a shipped name)
    sidecar = s.segmenter_config
    if sidecar is None and model is not None and model.is_file():
        sidecar = model.with_suffix(".json")  # an ONNX model's sidecar beside it
    return [("DATASET", config.input.dataset), ("--labels", config.input.labels),
            ("--weights", s.weights), ("--class-prior", s.class_prior), ("--segmenter", model),
            ("--segmenter-config", sidecar), ("--class-map", class_map),
            ("--instance-weights", config.objects.weights),
            ("--poses", None if poses in POSE_SOURCES else Path(poses))]


def check_run_paths(config: RunConfig) -> None:
    """``--out`` (a folder) and ``--rerun`` (a file) are checked against every input and the output policy, and
    every recorded input name is UTF-8, before anything is read or mapped."""
    check_out_dir(config.output.out)  # (a file, or below one: "nothing was mapped")
    inputs = [(name, path) for name, path in run_inputs(config) if path is not None]
    for name, path in inputs:
        check_utf8(path, name)
    check_outputs([("--out", config.output.out, OutputKind.FOLDER), ("--rerun", config.output.rerun, OutputKind.FILE)],
                  inputs)


def _resolved(path: Path) -> Path:
    return Path(os.path.abspath(path)).resolve(strict=False)


def staged_output(output: OutputConfig, stage: Path) -> OutputConfig:
    """``output`` with a ``--rerun`` file inside ``--out`` moved into the staging folder ``stage`` (the commit
    then renames it into ``--out`` with the other files, instead of deleting it with the old folder)."""
    if output.rerun is None:
        return output
    out, target = _resolved(output.out), _resolved(output.rerun)
    if not target.is_relative_to(out):
        return output
    return output.model_copy(update={"rerun": stage / target.relative_to(out)})
