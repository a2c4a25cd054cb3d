"""A segmenter scored on labelled frames in NYU-40 (``semmap eval-seg SEQ --segmenter NAME``): every network's
classes are brought to NYU-40 (its own label set folded into semmap's indoor classes, then semmap's classes to
NYU-40, :func:`semmap.labels.simulator_to_nyu40`), and scored over the classes both name: the NYU-40 classes the
segmenter can output that the ground truth holds, NYU-40's catch-all classes (other structure / furniture / prop)
left out. Every pixel with a label counts; a pixel the segmenter leaves ``unknown`` counts as wrong."""

from __future__ import annotations

from collections.abc import Callable, Iterable
from dataclasses import dataclass

import numpy as np

from semmap.errors import ConfigError
from semmap.eval.semantic import confusion, scores
from semmap.labels import INDOOR_LABELS, NYU40_NAMES, simulator_to_nyu40
from semmap.perception.base import Segmenter
from semmap.perception.structure.compose import fold_to
from semmap.types import Frame, LabelSet

#: The ground truth's class space: NYU-40 ids (0 void), or semmap's indoor classes (the simulator's).
GT_SPACES = ("nyu40", "semmap")
#: NYU-40's catch-all classes are never among the classes a segmenter names: a network that names bottles and
#: plants (semmap sends them to otherprop) names a sliver of otherprop, not the class (its pixels still count in
#: the pixel accuracy).
CATCH_ALL = frozenset(NYU40_NAMES.index(n) for n in ("otherstructure", "otherfurniture", "otherprop"))


def nyu40_of(label_set: LabelSet) -> np.ndarray:
    """(K,) NYU-40 id of each class of ``label_set`` (0: none), through semmap's indoor classes."""
    if tuple(label_set.names) == NYU40_NAMES:
        return np.arange(len(NYU40_NAMES), dtype=np.uint16)
    indoor, _ = fold_to(label_set)
    out = simulator_to_nyu40()[indoor]
    out[indoor == 0] = 0
    return out.astype(np.uint16)


def gt_space_of(label_set: LabelSet | None, choice: str | None = None) -> str:
    """The class space of a dataset's labels: ``choice`` when given, NYU-40 for a NYU-40 or unnamed label set,
    semmap's for the simulator's."""
    if choice is not None:
        if choice not in GT_SPACES:
            raise ConfigError(f"--gt-classes: {choice!r} is not one of {', '.join(GT_SPACES)}")
        return choice
    if label_set is not None and tuple(label_set.names) == tuple(INDOOR_LABELS.names):
        return "semmap"
    return "nyu40"


@dataclass(frozen=True)
class RealFrameScores:
    """Scores of one segmenter in NYU-40 over ``frames`` frames: MIoU over ``classes`` (the NYU-40 classes both
    name), pixel accuracy over every labelled pixel, per-class IoU and pixels, the (41, 41) confusion (rows the
    truth, columns the prediction)."""

    segmenter: str
    frames: int
    miou: float | None
    pixel_accuracy: float | None
    classes: tuple[str, ...]
    per_class: dict[str, dict]
    confusion: np.ndarray

    def to_dict(self) -> dict:
        return {"segmenter": self.segmenter, "frames": self.frames, "label_space": "nyu40",
                "miou": None if self.miou is None else round(self.miou, 4),
                "pixel_accuracy": None if self.pixel_accuracy is None else round(self.pixel_accuracy, 4),
                "classes": list(self.classes), "per_class": self.per_class, "confusion": self.confusion.tolist()}


def score_segmenter(frames: Iterable[Frame], segmenter: Segmenter, *, gt_space: str = "nyu40",
                    progress: Callable[[Iterable, int], Iterable] | None = None, total: int = 0) -> RealFrameScores:
    """Segment every frame and score it against its labels in NYU-40 (see the module docstring)."""
    pred_to_nyu = nyu40_of(segmenter.label_set)
    gt_to_nyu = simulator_to_nyu40() if gt_space == "semmap" else None
    k = len(NYU40_NAMES)
    conf = np.zeros((k, k), np.int64)
    n = 0
    for frame in (progress(frames, total) if progress else frames):
        if frame.labels is None:
            continue
        sem = segmenter.segment(frame)
        top = sem.labels[..., 0]
        pred = np.where(top < len(pred_to_nyu), pred_to_nyu[np.minimum(top, len(pred_to_nyu) - 1)], 0)
        gt = frame.labels if gt_to_nyu is None else gt_to_nyu[np.minimum(frame.labels, len(gt_to_nyu) - 1)]
        if int(gt.max(initial=0)) >= k:
            raise ConfigError(f"frame {frame.name}: label {int(gt.max())} is not a NYU-40 id (0-40); say which "
                              f"classes the labels are with --gt-classes")
        conf += confusion(pred.astype(np.int64), gt.astype(np.int64), k, ignore=0)
        n += 1
    names = getattr(segmenter, "output_classes", None)  # a segmenter that names only some of its label set's classes
    named = {int(c) for c in (pred_to_nyu if names is None else pred_to_nyu[np.asarray(names)])}
    nameable = sorted(named - {0} - CATCH_ALL)
    present = [c for c in nameable if conf[c].sum() > 0]
    s = scores(conf, ignore=0)
    per_class = {NYU40_NAMES[c]: {"iou": round(float(s.iou[c]), 4), "pixels": int(conf[c].sum())} for c in present}
    labelled = conf[1:].sum()
    return RealFrameScores(segmenter.name, n, float(np.mean([s.iou[c] for c in present])) if present else None,
                           float(np.trace(conf[1:, 1:]) / labelled) if labelled else None,
                           tuple(NYU40_NAMES[c] for c in present), per_class, conf)
