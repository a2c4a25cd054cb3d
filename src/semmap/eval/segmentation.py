"""2D segmentation metrics over folders of label images: MPA and MIoU (CBAM-PSPNet paper, eqs. 11-12).

With ``p_ij`` the number of pixels of true class ``i`` predicted as ``j`` (the confusion matrix):

- IoU_i = p_ii / (sum_j p_ij + sum_j p_ji - p_ii), MIoU = the mean of IoU_i (eq. 12);
- accuracy_i = p_ii / sum_j p_ij, MPA = the mean of accuracy_i (eq. 11).

Eq. 11 as printed divides the *total* correct pixels by the total and again by k+1, which would be the pixel
accuracy over k+1; the paper's text ("the proportion of correctly classified pixels of each class, then the
average") and its reported values are the per-class mean used here.  Means run over the classes present in
the ground truth (a class that is neither present nor predicted has IoU 0/0); ``ignore`` pixels are skipped.
"""

from __future__ import annotations

import json
import logging
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from semmap.datasets.base import read_label_image
from semmap.datasets.label_folder import LABELSET_FILE
from semmap.errors import ConfigError, DatasetError
from semmap.eval.semantic import SegmentationScores, confusion, scores, scores_from_counts
from semmap.files.atomic import write_text_atomic
from semmap.files.outputs import OutputKind, check_outputs
from semmap.limits import LIMITS, check
from semmap.types import LabelSet

LOG = logging.getLogger("semmap")

#: Label image suffixes looked for in prediction and ground-truth folders.
LABEL_SUFFIXES = (".png",)


#: Largest class count of label images (16-bit ids).
MAX_CLASSES = int(LIMITS["num_classes"].hi)
#: Up to this many classes the confusion matrix is kept (and written) dense; above it only its non-zero cells.
DENSE_CONFUSION_LIMIT = 1024


@dataclass(frozen=True)
class SegmentationEvaluation:
    """Scores of a set of predicted label images against ground truth, with the confusion counts."""

    scores: SegmentationScores
    pairs: np.ndarray  # (P, 3) int64 rows (true class, predicted class, pixels): the non-zero confusion cells
    num_classes: int
    images: int
    missing: tuple[str, ...]  # ground-truth images without a prediction (counted as not evaluated)
    label_set: LabelSet | None = None  # the classes' names (the dataset's labelset.json), when known
    label_set_path: Path | None = None  # where they were read from

    @property
    def confusion(self) -> np.ndarray:
        """(K, K) counts, rows = ground truth, columns = prediction (only for K up to the dense limit)."""
        if self.num_classes > DENSE_CONFUSION_LIMIT:
            raise ConfigError(f"a dense confusion matrix of {self.num_classes} classes is not built; use .pairs")
        conf = np.zeros((self.num_classes, self.num_classes), np.int64)
        conf[self.pairs[:, 0], self.pairs[:, 1]] = self.pairs[:, 2]
        return conf

    def to_dict(self, label_set: LabelSet | None = None) -> dict:
        """JSON-ready summary: MIoU, MPA, pixel accuracy (null where nothing was scored), per-class IoU and
        accuracy by class name (by id without a label set), and the confusion matrix (dense up to the limit,
        else its non-zero cells)."""
        s = self.scores
        label_set = label_set if label_set is not None else self.label_set
        names = label_set.names if label_set is not None else tuple(str(i) for i in range(len(s.iou)))
        per_class = {names[i]: {"iou": _finite(s.iou[i]), "accuracy": _finite(s.class_accuracy[i]),
                                "pixels": int(s.support[i])}
                     for i in np.flatnonzero(~np.isnan(s.iou))}
        confusion = (self.confusion.tolist() if self.num_classes <= DENSE_CONFUSION_LIMIT
                     else {"nonzero": self.pairs.tolist()})
        return {"miou": _finite(s.miou), "mpa": _finite(s.mpa), "pixel_accuracy": _finite(s.accuracy),
                "images": self.images, "missing_predictions": list(self.missing), "num_classes": self.num_classes,
                "label_set": None if self.label_set_path is None else str(self.label_set_path),
                "per_class": per_class, "confusion": confusion}


def _finite(value: float) -> float | None:
    """Rounded for JSON, or None (null) where the score is undefined (e.g. every pixel ignored)."""
    return round(float(value), 4) if np.isfinite(value) else None


def segmentation_scores(pred: np.ndarray, gt: np.ndarray, num_classes: int, *,
                        ignore: int | None = None) -> SegmentationScores:
    """Eq. 11-12 scores of one predicted label map (or a stack) against ground truth."""
    return scores(confusion(pred, gt, num_classes, ignore=ignore), ignore=ignore)


def label_pairs(pred_dir: Path, gt_dir: Path) -> Iterator[tuple[str, Path | None, Path]]:
    """(name, prediction or None, ground truth) for every ground-truth label image, matched by file stem."""
    for folder in (pred_dir, gt_dir):
        if not folder.is_dir():
            raise ConfigError(f"{folder}: not a folder of label images")
    preds = {p.stem: p for p in pred_dir.iterdir() if p.suffix.lower() in LABEL_SUFFIXES}
    gts = sorted(p for p in gt_dir.iterdir() if p.suffix.lower() in LABEL_SUFFIXES)
    if not gts:
        raise ConfigError(f"{gt_dir}: no ground-truth label images ({', '.join(LABEL_SUFFIXES)})")
    if not preds:
        raise ConfigError(f"{pred_dir}: no predicted label images ({', '.join(LABEL_SUFFIXES)})")
    for gt in gts:
        yield gt.stem, preds.get(gt.stem), gt


def find_label_set(gt_dir: str | Path) -> Path | None:
    """The ``labelset.json`` of a ground-truth label folder: inside it, or beside it (a sequence's ``labels/``
    folder and its ``labelset.json``, as ``semmap simulate`` writes them); None when there is none."""
    gt_dir = Path(gt_dir)
    return next((p for p in (gt_dir / LABELSET_FILE, gt_dir.parent / LABELSET_FILE) if p.is_file()), None)


def evaluate_label_folders(pred_dir: str | Path, gt_dir: str | Path, num_classes: int | None = None, *,
                           ignore: int | None = 255, resize: bool = False, out: str | Path | None = None,
                           label_set: str | Path | None = None) -> SegmentationEvaluation:
    """Accumulate the confusion of every predicted label PNG against the ground-truth PNG of the same name.

    The classes are those of ``label_set`` (a labelset.json; default: the one :func:`find_label_set` finds beside
    the ground truth): K and the names in the scores. ``num_classes`` sets K without one (it must agree with a
    label set); with neither, K is inferred from the largest id in the images. A prediction of another size than
    its ground truth is refused, or resized (nearest neighbour, with a warning) when ``resize``; a predicted id,
    or a ground-truth id other than ``ignore``, of K or more is refused, naming the file. Ground-truth images
    without a prediction are listed in ``missing``. Counts are kept sparse, so memory does not grow with K².
    With ``out``, the scores are also written there as JSON (checked against both folders before any image is
    read).
    """
    check_outputs([("--out", out, OutputKind.FILE)], [("PRED_DIR", pred_dir), ("GT_DIR", gt_dir)])
    check("num_classes", num_classes, "--num-classes")
    check("label_id", ignore, "--ignore")
    classes, classes_path, limit = _classes(Path(gt_dir), num_classes, label_set)
    codes = np.zeros(0, np.int64)
    counts = np.zeros(0, np.int64)
    missing: list[str] = []
    images, top = 0, 1
    for name, pred_path, gt_path in label_pairs(Path(pred_dir), Path(gt_dir)):
        if pred_path is None:
            missing.append(name)
            continue
        gt = read_label_image(gt_path)
        pred = _prediction_for(pred_path, gt_path, gt.shape, resize)
        keep = np.ones(gt.shape, bool) if ignore is None else gt != ignore
        if limit is not None:
            _check_ids(pred_path, pred, limit, "predicted")
            _check_ids(gt_path, gt[keep], limit, "ground-truth", hint=ignore is None)
        top = max(top, int(pred.max(initial=0)), int(gt[keep].max(initial=0)))
        new, n = np.unique(gt[keep].astype(np.int64) * _CODE_BASE + pred[keep], return_counts=True)
        codes, inverse = np.unique(np.concatenate([codes, new]), return_inverse=True)
        counts = np.bincount(inverse, weights=np.concatenate([counts, n]), minlength=len(codes)).astype(np.int64)
        images += 1
    if images == 0:
        raise DatasetError(f"{pred_dir}: no prediction matches a ground-truth image in {gt_dir} by name")
    k = limit[0] if limit is not None else top + 1
    pairs = np.stack([codes // _CODE_BASE, codes % _CODE_BASE, counts], axis=1).astype(np.int64)
    result = SegmentationEvaluation(_scores_of_pairs(pairs, k, ignore), pairs, k, images, tuple(missing),
                                    classes, classes_path)
    if out is not None:
        write_text_atomic(out, json.dumps(result.to_dict(), indent=2, allow_nan=False))
    return result


#: Confusion cells are coded ``true id * _CODE_BASE + predicted id`` (ids are 16-bit), whatever K turns out to be.
_CODE_BASE = MAX_CLASSES + 1


def _classes(gt_dir: Path, num_classes: int | None, label_set: str | Path | None
             ) -> tuple[LabelSet | None, Path | None, tuple[int, str] | None]:
    """The label set (and its file) and the class-id limit ``(K, how it was set)``; the limit is None when K is
    to be inferred from the images."""
    path = Path(label_set) if label_set is not None else find_label_set(gt_dir)
    classes = LabelSet.load(path) if path is not None else None
    if num_classes is not None and not 2 <= num_classes <= MAX_CLASSES:
        raise ConfigError(f"--num-classes must be in 2..{MAX_CLASSES} (label images hold 16-bit ids), "
                          f"got {num_classes}")
    if classes is None:
        return None, None, None if num_classes is None else (num_classes, f"--num-classes {num_classes}")
    if num_classes is not None and num_classes != len(classes):
        raise ConfigError(f"--num-classes {num_classes} disagrees with the {len(classes)} classes of {path}; "
                          f"leave --num-classes out (or pass --labelset)")
    return classes, path, (len(classes), f"the {len(classes)} classes of {path}")


def _prediction_for(pred_path: Path, gt_path: Path, shape: tuple[int, ...], resize: bool) -> np.ndarray:
    """The predicted label image, of its ground truth's size: refused when it differs, or resized by nearest
    neighbour (with a warning) when ``resize``."""
    pred = read_label_image(pred_path)
    if pred.shape == shape:
        return pred
    if not resize:
        raise DatasetError(f"{pred_path}: prediction is {pred.shape[1]}x{pred.shape[0]}, its ground truth "
                           f"{gt_path.name} {shape[1]}x{shape[0]} (pass --resize to resize "
                           f"predictions by nearest neighbour)")
    LOG.warning("%s: prediction is %dx%d, ground truth %dx%d; resized (nearest neighbour)", pred_path,
                pred.shape[1], pred.shape[0], shape[1], shape[0])
    return cv2.resize(pred, (shape[1], shape[0]), interpolation=cv2.INTER_NEAREST)


def _check_ids(path: Path, ids: np.ndarray, limit: tuple[int, str], what: str, *, hint: bool = False) -> None:
    top = int(ids.max(initial=0))
    if top >= limit[0]:
        extra = " (255 marks VOC boundaries: pass --ignore 255)" if hint and top == 255 else ""
        raise DatasetError(f"{path}: {what} class id {top} is not below {limit[1]}{extra}")


def _scores_of_pairs(pairs: np.ndarray, num_classes: int, ignore: int | None) -> SegmentationScores:
    """Eq. 11-12 scores from non-zero confusion cells (the same numbers as ``scores`` of the dense matrix)."""
    gt, pred, n = pairs[:, 0], pairs[:, 1], pairs[:, 2].astype(np.float64)
    tp = np.bincount(gt[gt == pred], weights=n[gt == pred], minlength=num_classes)
    gt_count = np.bincount(gt, weights=n, minlength=num_classes)
    pred_count = np.bincount(pred, weights=n, minlength=num_classes)
    return scores_from_counts(tp, gt_count, pred_count, ignore=ignore)
