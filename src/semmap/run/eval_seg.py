"""``semmap eval-seg SEQ --segmenter NAME``: a segmenter run over labelled frames (real ones: NYU-40 label PNGs)
and scored in NYU-40 over the classes both name (:mod:`semmap.eval.real_frames`)."""

from __future__ import annotations

import json
from pathlib import Path

from semmap.datasets import AUTO, open_dataset
from semmap.errors import ConfigError
from semmap.eval.real_frames import RealFrameScores, gt_space_of, score_segmenter
from semmap.files.atomic import write_text_atomic
from semmap.files.outputs import OutputKind, check_outputs
from semmap.limits import check
from semmap.perception.registry import SEGMENTERS, make_segmenter, split_segmenter, split_structure
from semmap.perception.structure.gravity import parse_up
from semmap.poses.base import Progress


def score_on_frames(sequence: Path, segmenter: str, *, weights: Path | None = None, labels: Path | None = None,
                    gt_classes: str | None = None, every: int = 1, max_frames: int | None = None,
                    format: str = AUTO, up: str | None = None, out: Path | None = None,
                    progress: Progress | None = None) -> RealFrameScores:
    """Score ``segmenter`` on every ``every``-th labelled frame of ``sequence`` in NYU-40; the scores also go to
    ``out`` (JSON) when given."""
    check("every_positive", every, "--every")
    if out is not None:
        check_outputs([("--out", out, OutputKind.FILE)], [("SEQ", sequence)])
    base, _ = split_structure(segmenter)
    name, _ = split_segmenter(base)
    if name not in SEGMENTERS:
        raise ConfigError(SEGMENTERS.unknown(name))
    dataset = open_dataset(sequence, format, labels=labels, stride=every, max_frames=max_frames)
    space = gt_space_of(dataset.label_set, gt_classes)
    seg = make_segmenter(segmenter, weights=weights, label_set=dataset.label_set,
                         up_world=None if up is None else parse_up(up))
    scores = score_segmenter(dataset, seg, gt_space=space, progress=progress, total=len(dataset))
    if scores.frames == 0:
        raise ConfigError(f"{sequence}: no frame has a label image (give the folder of them with --labels)")
    if out is not None:
        write_text_atomic(out, json.dumps(scores.to_dict(), indent=1) + "\n")
    return scores
