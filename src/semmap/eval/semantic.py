"""Semantic accuracy: confusion matrices, per-class IoU / mIoU and MPA (paper eqs. 11-12), in 2D and in 3D.

3D evaluation matches each occupied map voxel to the ground-truth surface voxels: the same key, or else the
nearest ground-truth voxel within ``tolerance`` cells (depth noise moves surfaces by a voxel).  Voxels with
no ground truth nearby count against geometric precision, not against the class scores; ground-truth voxels
never observed by the camera are reported as coverage, not as misses of a class.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from semmap.keys import coords_to_keys, index_in, pack_keys, unpack_keys
from semmap.types import EMPTY_LABEL, LabelSet


def confusion(pred: np.ndarray, gt: np.ndarray, num_classes: int, *, ignore: int | None = 0) -> np.ndarray:
    """(K, K) counts, rows = ground truth, columns = prediction; ``gt == ignore`` is skipped and predictions
    outside 0..K-1 (e.g. no class) are counted as class 0 (unknown)."""
    gt = np.asarray(gt).ravel().astype(np.int64)
    pred = np.asarray(pred).ravel().astype(np.int64)
    keep = (gt >= 0) & (gt < num_classes)
    if ignore is not None:
        keep &= gt != ignore
    gt, pred = gt[keep], pred[keep]
    pred = np.where((pred >= 0) & (pred < num_classes), pred, 0)
    return np.bincount(gt * num_classes + pred, minlength=num_classes * num_classes).reshape(num_classes, num_classes)


@dataclass(frozen=True)
class SegmentationScores:
    """Per-class IoU (NaN for classes absent from the ground truth), mIoU, pixel/voxel accuracy and MPA."""

    iou: np.ndarray
    miou: float
    accuracy: float
    mpa: float
    support: np.ndarray  # ground-truth count per class
    class_accuracy: np.ndarray  # p_ii / sum_j p_ij per class (NaN for classes absent from the ground truth)

    @property
    def fw_miou(self) -> float:
        """Frequency-weighted mIoU: each present class's IoU weighted by its share of the ground truth (the
        benchmarks' "f.w. IoU", e.g. ConceptGraphs' and Kimera-Semantics' evaluations)."""
        present = ~np.isnan(self.iou)
        weight = self.support[present].astype(np.float64)
        return float((self.iou[present] * weight).sum() / weight.sum()) if weight.sum() else float("nan")

    @property
    def mean_class_accuracy(self) -> float:
        """Mean of the per-class accuracies (the benchmarks' "mAcc"; the papers' MPA)."""
        return self.mpa

    def per_class(self, labels: LabelSet | None = None) -> dict[str, float]:
        names = labels.names if labels is not None else [str(i) for i in range(len(self.iou))]
        return {names[i]: round(float(v), 4) for i, v in enumerate(self.iou) if not np.isnan(v)}


def scores(conf: np.ndarray, *, ignore: int | None = 0) -> SegmentationScores:
    """IoU_c = TP / (TP + FP + FN) per class present in the ground truth (eq. 12), MPA = mean per-class
    accuracy (eq. 11 as usually implemented), accuracy = trace / total."""
    conf = conf.astype(np.float64)
    return scores_from_counts(np.diag(conf), conf.sum(axis=1), conf.sum(axis=0), ignore=ignore)


def scores_from_counts(tp: np.ndarray, gt_count: np.ndarray, pred_count: np.ndarray, *,
                       ignore: int | None = 0) -> SegmentationScores:
    """Eq. 11-12 scores from per-class true positives and ground-truth / predicted counts (K,) each."""
    present = gt_count > 0
    if ignore is not None and ignore < len(present):
        present[ignore] = False
    with np.errstate(divide="ignore", invalid="ignore"):
        iou = np.where(present, tp / (gt_count + pred_count - tp), np.nan)
        per_class_acc = np.where(present, tp / gt_count, np.nan)
    total = gt_count.sum()
    return SegmentationScores(iou, float(np.nanmean(iou)) if present.any() else float("nan"),
                              float(tp.sum() / total) if total else float("nan"),
                              float(np.nanmean(per_class_acc)) if present.any() else float("nan"),
                              gt_count.astype(np.int64), per_class_acc)


@dataclass(frozen=True)
class VoxelMatch:
    """Occupied map voxels paired with ground-truth classes, plus geometric precision and coverage."""

    pred: np.ndarray  # (M,) predicted class of each matched map voxel (EMPTY_LABEL -> 0)
    gt: np.ndarray  # (M,) ground-truth class
    precision: float  # matched / occupied map voxels
    coverage: float  # ground-truth voxels with a map voxel within tolerance / all ground-truth voxels
    map_voxels: int
    gt_voxels: int


_NEIGHBOURS = np.array([(dx, dy, dz) for dx in (-1, 0, 1) for dy in (-1, 0, 1) for dz in (-1, 0, 1)
                        if (dx, dy, dz) != (0, 0, 0)], np.int64)


def match_voxels(map_keys: np.ndarray, map_labels: np.ndarray, gt_keys: np.ndarray, gt_labels: np.ndarray,
                 *, tolerance: int = 1) -> VoxelMatch:
    """Pair each occupied map voxel (keys (M, 3), top class (M,)) with a ground-truth voxel: the same key,
    else (``tolerance`` = 1) a face/edge/corner neighbour, nearest first."""
    map_keys = np.asarray(map_keys, np.int64)
    gt_keys = np.asarray(gt_keys, np.int64)
    gt_packed = pack_keys(gt_keys)
    order = np.argsort(gt_packed)
    gt_sorted, gt_lab_sorted = gt_packed[order], np.asarray(gt_labels)[order]

    def lookup(keys: np.ndarray) -> np.ndarray:
        return index_in(gt_sorted, pack_keys(np.clip(keys, 0, 65535)))

    idx = lookup(map_keys)
    if tolerance >= 1:
        offsets = _NEIGHBOURS[np.argsort(np.abs(_NEIGHBOURS).sum(axis=1), kind="stable")]
        for off in offsets:
            missing = idx < 0
            if not missing.any():
                break
            idx[missing] = lookup(map_keys[missing] + off)
    matched = idx >= 0
    pred = np.asarray(map_labels)[matched].astype(np.int64)
    pred[pred == int(EMPTY_LABEL)] = 0
    covered = np.zeros(len(gt_sorted), bool)
    covered[idx[matched]] = True
    if tolerance >= 1 and len(gt_sorted):
        map_set = np.sort(pack_keys(map_keys))
        for off in _NEIGHBOURS:  # ground truth next to a map voxel is covered too
            covered |= index_in(map_set, pack_keys(np.clip(gt_keys[order] + off, 0, 65535))) >= 0
    return VoxelMatch(pred, gt_lab_sorted[idx[matched]].astype(np.int64),
                      float(matched.mean()) if len(matched) else float("nan"),
                      float(covered.mean()) if len(covered) else float("nan"),
                      len(map_keys), len(gt_keys))


def evaluate_map_3d(map_keys: np.ndarray, map_labels: np.ndarray, gt_keys: np.ndarray, gt_labels: np.ndarray,
                    label_set: LabelSet, *, tolerance: int = 1) -> dict:
    """Report entries for the semantic accuracy of occupied map voxels against ground-truth surface voxels."""
    match = match_voxels(map_keys, map_labels, gt_keys, gt_labels, tolerance=tolerance)
    s = scores(confusion(match.pred, match.gt, len(label_set)))
    return {
        "miou_3d": round(s.miou, 4),
        "voxel_accuracy_3d": round(s.accuracy, 4),
        "mpa_3d": round(s.mpa, 4),
        "per_class_iou_3d": s.per_class(label_set),
        "geometric_precision_3d": round(match.precision, 4),
        "gt_coverage_3d": round(match.coverage, 4),
        "gt_voxels": match.gt_voxels,
        "matched_voxels": len(match.gt),
    }


def evaluate_2d(conf: np.ndarray, label_set: LabelSet, prefix: str) -> dict:
    """Report entries for per-pixel segmentation scores accumulated over a run."""
    s = scores(conf)
    return {f"{prefix}_miou_2d": round(s.miou, 4), f"{prefix}_pixel_accuracy_2d": round(s.accuracy, 4),
            f"{prefix}_mpa_2d": round(s.mpa, 4), f"{prefix}_per_class_iou_2d": s.per_class(label_set)}


def cloud_keys_and_labels(centers: np.ndarray, labels: np.ndarray, resolution: float) -> tuple[np.ndarray, np.ndarray]:
    """Voxel keys (M, 3) at ``resolution`` of a map's voxels or points and one class per voxel: the most frequent
    class of the points inside (ties: the lower id; no class counts only where nothing else does)."""
    keys = coords_to_keys(centers, resolution)
    if len(keys) == 0:
        return keys.reshape(0, 3), np.zeros(0, np.uint16)
    packed = pack_keys(keys)
    uniq, inverse = np.unique(packed, return_inverse=True)
    if len(uniq) == len(packed):
        return keys, np.asarray(labels)
    lab = np.asarray(labels).astype(np.int64)
    none = lab == int(EMPTY_LABEL)
    lab = np.where(none, -1, lab)
    # count (voxel, class) pairs; the empty class ranks below every real one
    pair = inverse * (int(lab.max(initial=0)) + 2) + (lab + 1)
    pairs, counts = np.unique(pair, return_counts=True)
    vox, cls = pairs // (int(lab.max(initial=0)) + 2), pairs % (int(lab.max(initial=0)) + 2) - 1
    score = np.where(cls < 0, -1, counts)
    order = np.lexsort((cls, -score, vox))  # per voxel: highest count first, then lower id
    first = np.ones(len(order), bool)
    first[1:] = vox[order][1:] != vox[order][:-1]
    best = cls[order][first]
    return unpack_keys(uniq), np.where(best < 0, int(EMPTY_LABEL), best).astype(np.uint16)


def evaluate_cloud_3d(centers: np.ndarray, labels: np.ndarray, gt_keys: np.ndarray, gt_labels: np.ndarray,
                      label_set: LabelSet, resolution: float, *, tolerance: int = 1) -> dict:
    """:func:`evaluate_map_3d` for any map's voxels or points, voxelised at the ground truth's ``resolution``
    (a finer point map votes per voxel)."""
    keys, voxel_labels = cloud_keys_and_labels(centers, labels, resolution)
    return evaluate_map_3d(keys, voxel_labels, gt_keys, gt_labels, label_set, tolerance=tolerance)
