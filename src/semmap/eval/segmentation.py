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

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from semmap.datasets.base import read_label_image
from semmap.errors import ConfigError, DatasetError
from semmap.eval.semantic import SegmentationScores, confusion, scores
from semmap.types import LabelSet

#: Label image suffixes looked for in prediction and ground-truth folders.
LABEL_SUFFIXES = (".png",)


@dataclass(frozen=True)
class SegmentationEvaluation:
    """Scores of a set of predicted label images against ground truth, with the confusion matrix."""

    scores: SegmentationScores
    confusion: np.ndarray  # (K, K) rows = ground truth, columns = prediction
    images: int
    missing: tuple[str, ...]  # ground-truth images without a prediction (counted as not evaluated)

    def to_dict(self, label_set: LabelSet | None = None) -> dict:
        """JSON-ready summary: MIoU, MPA, pixel accuracy, per-class IoU and accuracy, confusion matrix."""
        s = self.scores
        names = label_set.names if label_set is not None else tuple(str(i) for i in range(len(s.iou)))
        per_class = {names[i]: {"iou": round(float(s.iou[i]), 4), "accuracy": round(float(s.class_accuracy[i]), 4),
                                "pixels": int(s.support[i])}
                     for i in range(len(s.iou)) if not np.isnan(s.iou[i])}
        return {"miou": round(s.miou, 4), "mpa": round(s.mpa, 4), "pixel_accuracy": round(s.accuracy, 4),
                "images": self.images, "missing_predictions": list(self.missing), "per_class": per_class,
                "confusion": self.confusion.tolist()}


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


def evaluate_label_folders(pred_dir: str | Path, gt_dir: str | Path, num_classes: int, *,
                           ignore: int | None = 255) -> SegmentationEvaluation:
    """Accumulate the confusion of every predicted label PNG against the ground-truth PNG of the same name.

    Predictions of another size than their ground truth are resized (nearest neighbour); ground-truth images
    without a prediction are listed in ``missing`` and left out.
    """
    if num_classes < 2:
        raise ConfigError(f"num_classes must be at least 2, got {num_classes}")
    conf = np.zeros((num_classes, num_classes), np.int64)
    missing: list[str] = []
    images = 0
    for name, pred_path, gt_path in label_pairs(Path(pred_dir), Path(gt_dir)):
        if pred_path is None:
            missing.append(name)
            continue
        gt = read_label_image(gt_path)
        pred = read_label_image(pred_path)
        if pred.shape != gt.shape:
            pred = cv2.resize(pred, (gt.shape[1], gt.shape[0]), interpolation=cv2.INTER_NEAREST)
        conf += confusion(pred, gt, num_classes, ignore=ignore)
        images += 1
    if images == 0:
        raise DatasetError(f"{pred_dir}: no prediction matches a ground-truth image in {gt_dir} by name")
    return SegmentationEvaluation(scores(conf, ignore=ignore), conf, images, tuple(missing))
