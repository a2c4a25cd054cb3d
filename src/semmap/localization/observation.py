"""Observation models: a frame reduced to a scan of camera-frame points with class sets, scored per particle.

Three models (``ObservationKind``):

- ``semantic`` (the default): a likelihood field (Thrun et al., *Probabilistic Robotics* ch. 6.4) of the
  endpoints against the map's occupied voxels, times the probability the nearest voxel gives the point's
  class distribution (:func:`semmap.localization._kernels.score_likelihood`).
- ``geometry``: the same likelihood field without the class term.
- ``cosine``: the semantic-voxel-grid paper's weight (Sec. IV-C): the frame as a local voxel map, its voxels'
  labels against the prior map's labels at the same voxels, cosine similarity as the weight.

The scan keeps one point per voxel of the map's resolution (a voxel filter in the camera frame) and a random
subset of at most ``max_points`` of them, so the cost of an update is particles x points lookups.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum
from functools import lru_cache

import numpy as np

from semmap.errors import ConfigError
from semmap.geometry import backproject
from semmap.localization import _kernels as kern
from semmap.localization.prior import PriorMap
from semmap.types import EMPTY_LABEL, CameraIntrinsics, TopKProbs

#: Points per scan by default: enough to pin a pose to a few centimetres, few enough for 10k particles.
DEFAULT_POINTS = 400
#: Back-projection samples about this many pixels before the voxel filter (pixel stride chosen from the image size).
SCAN_PIXELS = 20_000


class ObservationKind(str, Enum):
    """How a particle is scored against the prior map."""

    SEMANTIC = "semantic"  # likelihood field x class agreement (default)
    GEOMETRY = "geometry"  # likelihood field alone
    COSINE = "cosine"  # the paper's cosine similarity of voxel labels


@dataclass(frozen=True)
class LikelihoodParams:
    """Likelihood-field mixture: endpoint noise σ, hit / clutter weights, class-term floor and tempering."""

    sigma: float = 0.05  # metres: endpoint noise around the nearest occupied voxel centre
    z_hit: float = 0.8
    z_rand: float = 0.05
    semantic_floor: float = 0.2  # eps: share of the class term that ignores the classes (segmentation errors)
    effective_points: float = 40.0  # the scan counts as this many independent points (tempering, see filter)

    def __post_init__(self) -> None:
        if not self.sigma > 0 or not self.z_hit > 0 or not self.z_rand > 0:
            raise ConfigError("likelihood sigma, z_hit and z_rand must be positive")
        if not 0.0 <= self.semantic_floor <= 1.0:
            raise ConfigError(f"semantic floor must be in [0, 1], got {self.semantic_floor}")
        if not self.effective_points > 0:
            raise ConfigError(f"effective points must be positive, got {self.effective_points}")


@dataclass(frozen=True)
class Scan:
    """One frame's evidence in the camera frame: points (P, 3) float32 with top-k class sets (P, k) and their
    "others" mass (P,), -1 where a point has no classes; ``local_labels`` (P,) the most probable class of each
    point's voxel in the frame's local map (the cosine model's labels)."""

    points: np.ndarray
    labels: np.ndarray
    probs: np.ndarray
    others: np.ndarray
    local_labels: np.ndarray

    def __len__(self) -> int:
        return int(self.points.shape[0])

    @property
    def has_semantics(self) -> bool:
        return bool((self.others >= 0).any())


def make_scan(depth: np.ndarray, intrinsics: CameraIntrinsics, semantics: TopKProbs | None, *, resolution: float,
              max_points: int = DEFAULT_POINTS, rng: np.random.Generator, num_classes: int = 0,
              min_depth: float = 0.1, max_depth: float = 8.0) -> Scan:
    """Scan of a depth image (H, W) with optional per-pixel class sets (H, W, k): valid pixels back-projected
    (eq. 7), one point per ``resolution`` voxel kept, then at most ``max_points`` of them drawn at random.
    The local labels fuse the class sets of all points in a voxel (sum of probabilities, arg-max)."""
    if max_points < 1:
        raise ConfigError(f"a scan needs at least one point, got max_points={max_points}")
    stride = max(1, round(float(np.sqrt(depth.size / SCAN_PIXELS))))
    pts, pix = backproject(depth, intrinsics, min_depth=min_depth, max_depth=max_depth, stride=stride)
    if len(pts) == 0:
        k = 1 if semantics is None else semantics.k
        return Scan(np.zeros((0, 3), np.float32), np.full((0, k), EMPTY_LABEL, np.uint16), np.zeros((0, k), np.float32),
                    np.zeros(0, np.float32), np.zeros(0, np.uint16))
    cells = np.floor(pts / resolution).astype(np.int64)
    cells -= cells.min(axis=0)
    dims = cells.max(axis=0) + 1
    _, first, voxel = np.unique((cells[:, 0] * dims[1] + cells[:, 1]) * dims[2] + cells[:, 2], return_index=True,
                                return_inverse=True)
    k = 1 if semantics is None else semantics.k
    labels = np.full((len(pts), k), EMPTY_LABEL, np.uint16)
    probs = np.zeros((len(pts), k), np.float32)
    if semantics is not None:
        flat = semantics.reshape_flat()
        labels, probs = np.take(flat.labels, pix, axis=0), np.take(flat.probs, pix, axis=0)
    pick = first if len(first) <= max_points else rng.choice(first, max_points, replace=False)
    pick = np.sort(pick)
    lab, pr = np.ascontiguousarray(labels[pick]), np.ascontiguousarray(probs[pick], np.float32)
    has = ((lab != EMPTY_LABEL) & (pr > 0)).any(axis=1)
    others = np.where(has, np.clip(1.0 - pr.sum(axis=1), 0.0, 1.0), -1.0).astype(np.float32)
    local = np.zeros(len(pick), np.uint16)
    if semantics is not None:
        local = _fused_labels(voxel, labels, probs, num_classes)[voxel[pick]]
    return Scan(np.ascontiguousarray(pts[pick], np.float32), lab, pr, others, local)


def _fused_labels(voxel: np.ndarray, labels: np.ndarray, probs: np.ndarray, num_classes: int) -> np.ndarray:
    """Most probable class of each voxel (ids 0..V-1 per point) from the summed class sets of its points."""
    n_cls = max(num_classes, int(labels[labels != EMPTY_LABEL].max(initial=0)) + 1)
    n_vox = int(voxel.max()) + 1
    valid = labels != EMPTY_LABEL
    rows = np.broadcast_to(voxel[:, None], labels.shape)[valid]
    flat = np.bincount(rows * n_cls + labels[valid], weights=probs[valid], minlength=n_vox * n_cls)
    acc = flat.reshape(n_vox, n_cls)
    return acc.argmax(axis=1).astype(np.uint16)


def score(kind: ObservationKind, prior: PriorMap, R: np.ndarray, t: np.ndarray, scan: Scan,
          params: LikelihoodParams, out: np.ndarray) -> np.ndarray:
    """Log-weight update of each particle (R (N, 3, 3), t (N, 3)) for ``scan`` into ``out`` (N,): the tempered
    log-likelihood (``effective_points / P`` times the sum over points) for the likelihood models, the log of the
    cosine similarity for the paper's model."""
    nx, ny, nz = prior.shape
    inv_res = 1.0 / prior.resolution
    if len(scan) == 0:
        out[:] = 0.0
        return out
    if kind == ObservationKind.COSINE:
        if prior.class_probs is None:
            raise ConfigError("the cosine model needs a prior map with classes")
        kern.score_cosine(R, t, scan.points, scan.local_labels, prior.origin, inv_res, nx, ny, nz, prior.top_label,
                          out)
        np.log(np.maximum(out, 1e-6), out=out)
        return out
    semantic = kind == ObservationKind.SEMANTIC
    if semantic and prior.class_probs is None:
        raise ConfigError("the semantic model needs a prior map with classes (use --model geometry)")
    n_cls = max(prior.num_classes, 2)
    class_q = prior.class_q if prior.class_q is not None else np.zeros((1, n_cls), np.uint8)
    labels, probs, share = kernel_classes(scan, n_cls)
    tables = likelihood_tables(params, n_cls - 1)
    kern.score_likelihood(R, t, scan.points, labels, probs, share, prior.origin, prior.resolution, nx, ny, nz,
                          prior.nearest_packed, class_q, n_cls, semantic, params.semantic_floor, tables.geo,
                          tables.gauss, tables.log_mix, tables.d2_scale, tables.x_scale, math.log(params.z_rand), out)
    out *= params.effective_points / len(scan)
    return out


def kernel_classes(scan: Scan, num_classes: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The scan's class sets as the kernel reads them: classes outside 1..C-1 (void, empty slots) as class 0 with
    probability 0, and per point the "others" mass per real class outside its set (-1: the point has no
    classes), so that the kernel's inner loop has no branches."""
    valid = (scan.labels > 0) & (scan.labels < num_classes)
    labels = np.where(valid, scan.labels, 0).astype(np.uint16)
    probs = np.where(valid, scan.probs, 0.0).astype(np.float32)
    outside = (num_classes - 1) - valid.sum(axis=1)
    share = np.where(outside > 0, np.maximum(scan.others, 0.0) / np.maximum(outside, 1), 0.0)
    share = np.where(scan.others < 0, -1.0, share).astype(np.float32)
    return np.ascontiguousarray(labels), np.ascontiguousarray(probs), share


@dataclass(frozen=True)
class LikelihoodTables:
    """The likelihood-field mixture tabulated: over d² (up to (4σ)², the last entry standing for any larger
    distance) ``geo`` = log(z_hit · g + z_rand) and ``gauss`` = g = exp(-d²/2σ²); over x = g · f (up to the class
    term's largest value) ``log_mix`` = log(z_hit · x + z_rand).  Small enough to stay in the L1/L2 cache."""

    geo: np.ndarray  # (D_BINS,) float64
    gauss: np.ndarray  # (D_BINS,) float64
    log_mix: np.ndarray  # (X_BINS,) float64
    d2_scale: float  # index = round(d² · d2_scale)
    x_scale: float  # index = round(x · x_scale)


D_BINS, X_BINS = 1024, 4096


@lru_cache(maxsize=16)
def likelihood_tables(params: LikelihoodParams, real_classes: int) -> LikelihoodTables:
    """Tables of the likelihood-field mixture for ``params`` and a label set of ``real_classes`` classes."""
    d2_max = (4.0 * params.sigma) ** 2
    d2_scale = (D_BINS - 2) / d2_max
    g = np.exp(-np.arange(D_BINS) / d2_scale / (2.0 * params.sigma**2))
    g[-1] = 0.0  # beyond 4 σ
    x_max = (1.0 - params.semantic_floor) * real_classes + params.semantic_floor
    x_scale = (X_BINS - 1) / x_max
    log_mix = np.log(params.z_hit * np.arange(X_BINS) / x_scale + params.z_rand)
    return LikelihoodTables(np.log(params.z_hit * g + params.z_rand), g, log_mix, float(d2_scale), float(x_scale))


def fit(prior: PriorMap, T_world_cam: np.ndarray, scan: Scan, max_distance: float) -> float:
    """Share of the scan's points within ``max_distance`` of an occupied voxel centre when placed by one pose."""
    T = np.asarray(T_world_cam, np.float64)
    nx, ny, nz = prior.shape
    return float(kern.inlier_fraction(np.ascontiguousarray(T[:3, :3]), np.ascontiguousarray(T[:3, 3]), scan.points,
                                      prior.origin, 1.0 / prior.resolution, nx, ny, nz, prior.nearest, prior.centers,
                                      max_distance**2))
