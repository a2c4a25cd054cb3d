"""``semmap eval-map``: an existing map scored at the pixels of a labelled sequence, beside a network's labels, and
at a dataset's labelled points or mesh vertices (``--gt-ply``: mIoU, f.w. mIoU, mAcc as the benchmarks report them).

The map is read with the map readers (``io.map_files.load_map``), the sequence with the dataset readers, the network
labels come from ``--segmenter`` (``precomputed --weights FOLDER`` for predictions stored as files), and the
scoring is ``eval.pixels``: the final map only (there is no causal variant for a finished map).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from semmap.errors import ConfigError
from semmap.eval.pixels import EVERY, PixelScores, frame_sample, fusion_ceiling, map_labels_at
from semmap.geometry import DEFAULT_MAX_DEPTH, DEFAULT_MIN_DEPTH
from semmap.poses.base import Progress


def evaluate_map_file(map_path: Path, sequence: Path, *, format: str = "auto", segmenter: str | None = None,
                      weights: Path | None = None, every: int = EVERY, stride: int = 1, max_frames: int | None = None,
                      min_depth: float = DEFAULT_MIN_DEPTH, max_depth: float = DEFAULT_MAX_DEPTH,
                      out: Path | None = None, progress: Progress | None = None) -> dict:
    """Map-at-pixel scores of the map file ``map_path`` (a ``.semmap`` of any map, or a run folder holding
    ``map.semmap``) on every ``every``-th frame of ``sequence`` (its labels and its own poses: a map built from
    those poses), beside ``segmenter``'s labels at the same pixels when given; written as JSON to ``out``."""
    from semmap.datasets import open_dataset
    from semmap.files.atomic import write_text_atomic
    from semmap.files.outputs import OutputKind, check_outputs
    from semmap.products.export import load_product_map

    check_outputs([("--out", out, OutputKind.FILE)], [("MAP", map_path), ("SEQ", sequence)])
    if every < 1 or stride < 1:
        raise ConfigError(f"--every and --pixel-stride must be at least 1, got {every} and {stride}")
    m, path = load_product_map(Path(map_path))
    if m.label_set is None:
        raise ConfigError(f"{path}: the map holds no classes; a map built with semantics is needed")
    dataset = open_dataset(sequence, format, max_frames=max_frames)
    net = _segmenter(segmenter, weights, dataset)
    acc = PixelScores(len(m.label_set))
    kept: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
    frames = progress(iter(dataset), len(dataset)) if progress is not None else dataset
    for i, frame in enumerate(frames):
        if i % every or frame.T_world_cam is None or frame.labels is None:
            continue
        sem = net.segment(frame) if net is not None else None
        s = frame_sample(frame, frame.T_world_cam, sem, min_depth=min_depth, max_depth=max_depth, stride=stride)
        acc.add(s.gt, s.net if net is not None else None, map_labels_at(m, s.points))
        if net is not None:
            kept.append((s.points, s.gt, s.net))
    if acc.frames == 0:
        raise ConfigError(f"{sequence}: no frame (of every {every}th) has both a pose and a label image to score "
                          "the map at")
    result = {"map": str(path), "kind": m.kind.value, "sequence": str(sequence), "pixel_every": every,
              "pixel_stride": stride, "pixel_frames": acc.frames, "segmenter": segmenter, **acc.summary()}
    if kept:
        result.update(fusion_ceiling(*(np.concatenate(part) for part in zip(*kept, strict=True)), m.resolution))
    if out is not None:
        write_text_atomic(out, json.dumps(result, indent=2))
    return result


def _segmenter(name: str | None, weights: Path | None, dataset):
    """The segmenter ``name`` predicting the dataset's classes where it needs them, or None."""
    if name is None:
        if weights is not None:
            raise ConfigError("--weights needs --segmenter (precomputed for a folder of predictions)")
        return None
    from semmap.perception.registry import SEGMENTERS, make_segmenter, split_segmenter

    entry = SEGMENTERS[split_segmenter(name)[0]]  # (onnx:MODEL.onnx, hf:MODEL_ID: the user's own model)
    label_set = dataset.label_set if entry.dataset_classes else None
    return make_segmenter(name, weights=weights, label_set=label_set)


def evaluate_map_points(map_path: Path, gt_ply: Path, *, label_property: str = "label",
                        out: Path | None = None) -> dict:
    """The map file ``map_path`` (a ``.semmap``, or a run folder holding ``map.semmap``) scored at the labelled
    vertices of ``gt_ply`` (``eval.labelled_points``: each takes the map's class at its position, nearest occupied
    voxel otherwise); written as JSON to ``out``."""
    from semmap.eval.labelled_points import point_scores
    from semmap.files.atomic import write_text_atomic
    from semmap.files.outputs import OutputKind, check_outputs
    from semmap.io.labelled_ply import read_labelled_vertices
    from semmap.products.export import load_product_map

    check_outputs([("--out", out, OutputKind.FILE)], [("MAP", map_path), ("--gt-ply", gt_ply)])
    m, path = load_product_map(Path(map_path))
    points, labels = read_labelled_vertices(gt_ply, label_property)
    result = {"map": str(path), "kind": m.kind.value, "gt_ply": str(gt_ply), "gt_label_property": label_property,
              **point_scores(m, points, labels, source=str(gt_ply))}
    if out is not None:
        write_text_atomic(out, json.dumps(result, indent=2))
    return result
