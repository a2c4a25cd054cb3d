"""A map scored at a dataset's labelled points or mesh vertices, as ConceptGraphs' and Kimera-Semantics'
evaluations score theirs: each ground-truth point takes the class of the map at its position (the occupied voxel
holding it, else the nearest occupied voxel, as their nearest-neighbour lookups do), and one confusion matrix over
all points gives mIoU, frequency-weighted mIoU, mean class accuracy (mAcc) and overall accuracy.

Ground-truth class 0 (unannotated / unknown, as in ScanNet's NYU-40 labels) is left out; means run over the
classes present in the ground truth. The share of points farther than one voxel diagonal from any occupied voxel
is reported beside the scores (space the map never saw costs accuracy, not only coverage). Ground truth that
hardly meets the map (another frame, another unit) is refused rather than scored; a map that saw less than half of
it gets a warning.
"""

from __future__ import annotations

import logging

import numpy as np

from semmap.errors import ConfigError
from semmap.eval.semantic import confusion, scores
from semmap.maps.base import SemanticMap
from semmap.types import EMPTY_LABEL

LOG = logging.getLogger("semmap")
#: Ground truth of which at most this share lies within a voxel diagonal of the map is not of the map's frame.
MIN_NEAR_SHARE = 0.05
#: Above this share of points beyond a voxel, the scores are mostly of space the map never saw: a warning.
WARN_FAR_SHARE = 0.5


def classes_at_points(m: SemanticMap, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The map's class at each (N, 3) point (its occupied voxel, else the nearest occupied voxel's) and the
    distance (m) to that voxel's centre (0 where a voxel holds the point); EMPTY_LABEL where the map is empty."""
    from scipy.spatial import cKDTree

    labels = np.asarray(m.class_at(points)[0], np.uint16).copy()
    dist = np.zeros(len(points))
    missing = np.flatnonzero(labels == EMPTY_LABEL)
    cloud = m.cloud()
    has = cloud.labels != EMPTY_LABEL
    if len(missing) and has.any():
        d, i = cKDTree(cloud.centers[has]).query(np.asarray(points)[missing])
        labels[missing] = cloud.labels[has][i]
        dist[missing] = d
    elif len(missing):
        dist[missing] = np.inf
    return labels, dist


def point_scores(m: SemanticMap, points: np.ndarray, gt: np.ndarray, *, source: str = "ground truth") -> dict:
    """mIoU, f.w. mIoU, mAcc and accuracy of ``m`` at ground-truth ``points`` (N, 3) of classes ``gt`` (N,)."""
    if m.label_set is None:
        raise ConfigError("the map holds no classes; a map built with semantics is needed")
    k = len(m.label_set)
    gt = np.asarray(gt, np.int64)
    if len(gt) and (gt.min() < 0 or gt.max() >= k):
        raise ConfigError(f"{source}: class id {int(gt.max() if gt.max() >= k else gt.min())} is outside the map's "
                          f"label set (0..{k - 1}); the ground truth must use the map's class ids")
    keep = gt != 0
    if not keep.any():
        raise ConfigError(f"{source}: no point has a class other than 0 (unannotated)")
    pred, dist = classes_at_points(m, np.asarray(points, np.float64)[keep])
    s = scores(confusion(np.where(pred == EMPTY_LABEL, 0, pred), gt[keep], k))
    names = m.label_set.names
    far = float(np.mean(dist > np.sqrt(3) * float(m.resolution)))
    _check_frame(m, np.asarray(points, np.float64)[keep], far, source)
    return {"gt_points": int(keep.sum()), "gt_points_unannotated": int((~keep).sum()),
            "points_miou": _r(s.miou), "points_fw_miou": _r(s.fw_miou), "points_mean_class_accuracy":
                _r(s.mean_class_accuracy), "points_accuracy": _r(s.accuracy),
            "points_beyond_a_voxel": _r(far),
            "points_per_class_iou": {names[i]: _r(v) for i, v in enumerate(s.iou) if not np.isnan(v)}}


def _check_frame(m: SemanticMap, points: np.ndarray, far: float, source: str) -> None:
    """Refuse ground truth that does not meet the map (one line with both extents), warn when most of it lies
    beyond the map's voxels."""
    if 1.0 - far <= MIN_NEAR_SHARE:
        centers = m.cloud().centers

        def extent(p: np.ndarray) -> str:
            lo, hi = p.min(axis=0), p.max(axis=0)
            return ", ".join(f"{a} {lo[i]:.1f}..{hi[i]:.1f}" for i, a in enumerate("xyz"))

        raise ConfigError(f"{source}: {100 * far:.1f} % of its labelled points lie farther than a voxel diagonal from "
                          f"every occupied voxel of the map (map {extent(centers) if len(centers) else 'empty'} m; "
                          f"ground truth {extent(points)}): is it in the map's frame and in metres?")
    if far > WARN_FAR_SHARE:
        LOG.warning(f"{source}: {100 * far:.1f} % of the labelled points lie farther than a voxel diagonal from "
                    f"the map: the scores are mostly of space the map never saw")


def _r(v: float) -> float | None:
    return round(float(v), 4) if np.isfinite(v) else None
