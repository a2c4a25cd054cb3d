"""DeepSORT (Wojke et al. 2017) over instance detections, as the object-oriented SLAM paper runs it (Sec. 3.1).

Per frame: every track's box is first moved by the camera's own motion when the frame's pose is known (camera-motion
compensation, an addition for hand-held cameras), then predicted by the Kalman filter (eqs. 1-2); detections are
matched to confirmed tracks in a cascade by track age (tracks seen one frame ago first), on a weighted sum of the
box's Mahalanobis distance and the cosine distance of appearance features (DeepSORT's eq. 5), each gated
(chi-square 95 %, largest cosine distance); the remaining detections are matched to tentative tracks and to tracks
missed for one frame by box IoU; matched tracks are updated (eqs. 3-7), unmatched detections start tentative
tracks. A track is confirmed after ``n_init`` consecutive hits; a tentative track missed once, or a confirmed one
missed more than ``max_age`` frames, is deleted. Each assignment is solved with
``scipy.optimize.linear_sum_assignment``. Matching ignores the class, as DeepSORT does; each track keeps
score-weighted class votes, so an object sometimes called by a similar class keeps one track. Features are the
source's (network) features when it has them, else colour histograms of the masks
(:mod:`semmap.perception.tracking.appearance`).
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

import numba as nb
import numpy as np
from scipy.optimize import linear_sum_assignment

from semmap.errors import ConfigError
from semmap.perception.tracking import kalman
from semmap.perception.tracking.appearance import colour_histograms
from semmap.types import Frame, Instances, invert_pose

#: Cost given to gated-out pairs before the assignment (anything above every threshold).
_INFEASIBLE = 1e5


class TrackState(int, Enum):
    """DeepSORT's track life cycle."""

    TENTATIVE = 1
    CONFIRMED = 2
    DELETED = 3


@dataclass(frozen=True)
class DeepSortParams:
    """Settings of :class:`DeepSort` (DeepSORT's defaults, but for the cosine threshold of colour histograms)."""

    max_cosine_distance: float = 0.3  #: appearance gate (DeepSORT: 0.2 for its re-identification network)
    #: weight of the gated Mahalanobis distance (over its gate) against the cosine distance in the cascade's cost
    #: (DeepSORT's lambda; it uses 0 with a re-identification network, but colour histograms of neighbouring
    #: look-alikes, books on a shelf, need the box position too)
    motion_weight: float = 0.5
    max_iou_distance: float = 0.7  #: 1 - IoU gate of the IoU matching
    max_age: int = 30  #: frames a confirmed track survives without a detection
    n_init: int = 3  #: consecutive hits that confirm a track
    budget: int = 30  #: appearance features kept per track (the newest)
    min_score: float = 0.3  #: detections below this score are not tracked
    #: report each tracked detection with its track's class (score-weighted votes of every frame it was seen in):
    #: "the target tracking algorithm can reduce wrong results through data associations" (the paper, Sec. 4.2)
    vote_classes: bool = True

    def __post_init__(self) -> None:
        if not (0 < self.max_cosine_distance <= 2 and 0 < self.max_iou_distance <= 1):
            raise ConfigError("DeepSORT: max_cosine_distance in (0, 2] and max_iou_distance in (0, 1]")
        if self.max_age < 1 or self.n_init < 1 or self.budget < 1:
            raise ConfigError("DeepSORT: max_age, n_init and budget must be at least 1")


@dataclass
class _Track:
    track_id: int
    state: TrackState
    hits: int = 1
    time_since_update: int = 0
    features: np.ndarray | None = None  # (<= budget, D) newest last
    votes: np.ndarray | None = None  # class votes (score-weighted)
    depth: float = 0.0  # metres, mean depth of the last matched mask (0: unknown)


class DeepSort:
    """Online multi-object tracker; :meth:`update` names every detection of a frame with a track id."""

    def __init__(self, params: DeepSortParams | None = None, num_classes: int = 1) -> None:
        self.params = DeepSortParams() if params is None else params
        self.num_classes = max(int(num_classes), 1)
        self.tracks: list[_Track] = []
        self._mean = np.zeros((0, 8))
        self._cov = np.zeros((0, 8, 8))
        self._next_id = 1
        self._last_pose: np.ndarray | None = None
        self.frames = 0

    # ------------------------------------------------------------------ public
    def update(self, instances: Instances, frame: Frame | None = None,
               T_world_cam: np.ndarray | None = None) -> Instances:
        """Track one frame's detections; returns them with ``track_ids`` (0 for detections below ``min_score``) and,
        with ``vote_classes``, each tracked detection's class replaced by its track's.

        Features are ``instances.features`` when present, else colour histograms of the masks in ``frame.rgb``.
        With the camera pose of this frame (and the frame's depth), each track's predicted box is first moved by
        the camera's motion since the previous frame (camera-motion compensation, see :meth:`_compensate`).
        """
        p = self.params
        self.frames += 1
        self._compensate(frame, T_world_cam)
        self._predict()
        n = len(instances)
        feats = instances.features
        if feats is None:
            feats = colour_histograms(frame.rgb, instances.ids, n) if frame is not None \
                else np.zeros((n, 1), np.float32)
        depth = mask_depths(frame.depth, instances.ids, n) if frame is not None else np.zeros(n)
        usable = np.flatnonzero(instances.scores >= p.min_score)
        z = kalman.boxes_to_measurements(instances.boxes)
        matches, unmatched = self._associate(z[usable], feats[usable])
        track_ids = np.zeros(n, np.int32)
        if matches:
            t_idx = np.array([m[0] for m in matches])
            d_idx = usable[np.array([m[1] for m in matches])]
            self._mean[t_idx], self._cov[t_idx] = kalman.update(self._mean[t_idx], self._cov[t_idx], z[d_idx])
            for t, d in zip(t_idx, d_idx, strict=True):
                self._hit(self.tracks[t], feats[d], int(instances.class_ids[d]), float(instances.scores[d]))
                self.tracks[t].depth = depth[d] if depth[d] > 0 else self.tracks[t].depth
                track_ids[d] = self.tracks[t].track_id
        matched_tracks = {m[0] for m in matches}
        for t, track in enumerate(self.tracks):
            if t not in matched_tracks:
                self._miss(track)
        new = usable[np.asarray(unmatched, np.int64)]
        for d in new:
            track_ids[d] = self._start(z[d], feats[d], int(instances.class_ids[d]), float(instances.scores[d]))
            self.tracks[-1].depth = float(depth[d])
        classes = instances.class_ids
        if self.params.vote_classes:  # each detection takes its track's class by the votes of all its frames
            alive = {t.track_id: t for t in self.tracks}
            classes = np.array([int(np.argmax(alive[t].votes)) if t in alive else c
                                for t, c in zip(track_ids.tolist(), instances.class_ids.tolist(), strict=True)],
                               np.int32)
        self._drop_deleted()
        return instances.with_(track_ids=track_ids, class_ids=classes)

    def class_of(self, track_id: int) -> int | None:
        """Most voted class of a live track (None when it is gone)."""
        for t in self.tracks:
            if t.track_id == track_id:
                return int(np.argmax(t.votes))
        return None

    def confirmed_ids(self) -> list[int]:
        return [t.track_id for t in self.tracks if t.state == TrackState.CONFIRMED]

    # ------------------------------------------------------------------ steps
    def _compensate(self, frame: Frame | None, T_world_cam: np.ndarray | None) -> None:
        """Move each track's box by the image motion the camera's own motion since the last frame gives its
        centre at the track's last depth: back-project, transform by ``T_cur_prev``, project; the height scales
        with the depth ratio. A hand-held camera turning 30 degrees/s moves objects 10 px per frame, as far as
        neighbouring books are apart, which a constant-velocity filter started at rest cannot follow."""
        prev, self._last_pose = self._last_pose, None if T_world_cam is None else np.asarray(T_world_cam, float)
        if prev is None or self._last_pose is None or frame is None or not self.tracks:
            return
        T = invert_pose(self._last_pose) @ prev  # previous camera frame -> current camera frame
        z = np.array([t.depth for t in self.tracks])
        ok = z > 0
        if not ok.any():
            return
        c = frame.intrinsics
        m = self._mean[ok]
        X = np.column_stack([(m[:, 0] - c.cx) / c.fx * z[ok], (m[:, 1] - c.cy) / c.fy * z[ok], z[ok]])
        Y = X @ T[:3, :3].T + T[:3, 3]
        front = Y[:, 2] > 1e-3
        rows = np.flatnonzero(ok)[front]
        Y = Y[front]
        self._mean[rows, 0] = c.fx * Y[:, 0] / Y[:, 2] + c.cx
        self._mean[rows, 1] = c.fy * Y[:, 1] / Y[:, 2] + c.cy
        self._mean[rows, 3] *= z[rows] / Y[:, 2]
        for r, depth in zip(rows, Y[:, 2], strict=True):
            self.tracks[r].depth = float(depth)

    def _predict(self) -> None:
        if self.tracks:
            self._mean, self._cov = kalman.predict(self._mean, self._cov)
            for t in self.tracks:
                t.time_since_update += 1

    def _associate(self, z: np.ndarray, feats: np.ndarray) -> tuple[list[tuple[int, int]], list[int]]:
        """(track, detection) matches of the cascade and the IoU stage, and the unmatched detections."""
        p = self.params
        unmatched = list(range(len(z)))
        matches: list[tuple[int, int]] = []
        confirmed = [i for i, t in enumerate(self.tracks) if t.state == TrackState.CONFIRMED]
        if confirmed and unmatched:
            maha = kalman.gating_distance(self._mean[confirmed], self._cov[confirmed], z)
            appearance = self._appearance_cost(confirmed, feats)
            cost_all = p.motion_weight * maha / kalman.CHI2_GATE_4DOF + (1.0 - p.motion_weight) * appearance
            cost_all[(maha > kalman.CHI2_GATE_4DOF) | (appearance > p.max_cosine_distance)] = _INFEASIBLE
            ages = np.array([self.tracks[i].time_since_update for i in confirmed])
            for level in np.unique(ages[(ages >= 1) & (ages <= p.max_age)]).tolist():  # cascade: most recent first
                if not unmatched:
                    break
                rows = np.flatnonzero(ages == level)
                found = _assign(cost_all[np.ix_(rows, unmatched)], 1.0)
                matches += [(confirmed[rows[r]], unmatched[c]) for r, c in found]
                taken = {unmatched[c] for _, c in found}
                unmatched = [d for d in unmatched if d not in taken]
        matched = {m[0] for m in matches}
        candidates = [i for i, t in enumerate(self.tracks) if i not in matched
                      and (t.state == TrackState.TENTATIVE or t.time_since_update == 1)]
        if candidates and unmatched:
            boxes_t = kalman.measurements_to_boxes(self._mean[candidates, :4])
            boxes_d = kalman.measurements_to_boxes(z[unmatched])
            found = _assign(1.0 - box_iou(boxes_t, boxes_d), p.max_iou_distance)
            matches += [(candidates[r], unmatched[c]) for r, c in found]
            taken = {unmatched[c] for _, c in found}
            unmatched = [d for d in unmatched if d not in taken]
        return matches, unmatched

    def _appearance_cost(self, rows: list[int], feats: np.ndarray) -> np.ndarray:
        """(len(rows), N) smallest cosine distance between each track's kept features and each detection's."""
        cost = np.ones((len(rows), len(feats)))
        usable = [r for r, i in enumerate(rows) if self.tracks[i].features is not None
                  and self.tracks[i].features.shape[1] == feats.shape[1] and len(self.tracks[i].features)]
        if not usable or not len(feats):
            return cost
        galleries = [self.tracks[rows[r]].features for r in usable]
        starts = np.cumsum([0] + [len(g) for g in galleries[:-1]])
        similarity = feats @ np.concatenate(galleries).T  # (N, all kept features): one product for every track
        cost[usable] = 1.0 - np.maximum.reduceat(similarity, starts, axis=1).T
        return cost

    def _hit(self, track: _Track, feat: np.ndarray, cls: int, score: float) -> None:
        track.hits += 1
        track.time_since_update = 0
        if track.state == TrackState.TENTATIVE and track.hits >= self.params.n_init:
            track.state = TrackState.CONFIRMED
        gallery = feat[None] if track.features is None else np.vstack([track.features, feat[None]])
        track.features = gallery[-self.params.budget:]
        track.votes[min(cls, self.num_classes - 1)] += score

    def _miss(self, track: _Track) -> None:
        if track.state == TrackState.TENTATIVE or track.time_since_update > self.params.max_age:
            track.state = TrackState.DELETED

    def _start(self, z: np.ndarray, feat: np.ndarray, cls: int, score: float) -> int:
        mean, cov = kalman.initiate(z[None])
        self._mean = np.concatenate([self._mean, mean])
        self._cov = np.concatenate([self._cov, cov])
        votes = np.zeros(self.num_classes)
        votes[min(cls, self.num_classes - 1)] = score
        state = TrackState.CONFIRMED if self.params.n_init <= 1 else TrackState.TENTATIVE
        self.tracks.append(_Track(self._next_id, state, features=feat[None].copy(), votes=votes))
        self._next_id += 1
        return self._next_id - 1

    def _drop_deleted(self) -> None:
        alive = [i for i, t in enumerate(self.tracks) if t.state != TrackState.DELETED]
        if len(alive) != len(self.tracks):
            self.tracks = [self.tracks[i] for i in alive]
            self._mean, self._cov = self._mean[alive], self._cov[alive]


def _assign(cost: np.ndarray, max_cost: float) -> list[tuple[int, int]]:
    """Minimum-cost one-to-one matches (row, column) of a cost matrix, keeping pairs with cost <= ``max_cost``."""
    if cost.size == 0:
        return []
    c = np.where(cost > max_cost, _INFEASIBLE, cost)
    rows, cols = linear_sum_assignment(c)
    ok = c[rows, cols] <= max_cost
    return list(zip(rows[ok].tolist(), cols[ok].tolist(), strict=True))


def box_iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(len(a), len(b)) IoU of inclusive pixel boxes ``x0, y0, x1, y1``."""
    a = np.asarray(a, np.float64).reshape(-1, 4)
    b = np.asarray(b, np.float64).reshape(-1, 4)
    lt = np.maximum(a[:, None, :2], b[None, :, :2])
    rb = np.minimum(a[:, None, 2:], b[None, :, 2:])
    wh = np.clip(rb - lt + 1.0, 0.0, None)
    inter = wh[..., 0] * wh[..., 1]
    area_a = (a[:, 2] - a[:, 0] + 1) * (a[:, 3] - a[:, 1] + 1)
    area_b = (b[:, 2] - b[:, 0] + 1) * (b[:, 3] - b[:, 1] + 1)
    return inter / np.maximum(area_a[:, None] + area_b[None, :] - inter, 1e-9)


def mask_depths(depth: np.ndarray, ids: np.ndarray, n: int, stride: int = 4) -> np.ndarray:
    """(n,) mean valid depth (metres) of masks 1..n over every ``stride``-th pixel (0 where none has depth)."""
    return _mask_depths(np.asarray(depth), np.asarray(ids), n, stride)


@nb.njit(cache=True)
def _mask_depths(depth: np.ndarray, ids: np.ndarray, n: int, stride: int) -> np.ndarray:
    sums = np.zeros(n)
    counts = np.zeros(n, np.int64)
    for v in range(0, ids.shape[0], stride):
        for u in range(0, ids.shape[1], stride):
            k = ids[v, u]
            d = np.float64(depth[v, u])
            if 1 <= k <= n and d > 0 and np.isfinite(d):
                sums[k - 1] += d
                counts[k - 1] += 1
    out = np.zeros(n)
    for k in range(n):
        if counts[k] > 0:
            out[k] = sums[k] / counts[k]
    return out
