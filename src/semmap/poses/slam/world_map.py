"""The SLAM map: keyframes, landmarks (growable arrays) and the keyframe-landmark observation table."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from semmap.poses.slam.features import FrameFeatures


@dataclass
class Keyframe:
    """A frame kept in the map: its pose, its keypoints and which landmark (or -1) each keypoint observes."""

    id: int
    frame: int  # index in the system's frame log
    T_wc: np.ndarray  # (4, 4) camera-to-world, revised by bundle adjustment and loop closure
    feats: FrameFeatures
    lm: np.ndarray  # (N,) int64 landmark id per keypoint, -1 for none
    retrieval: np.ndarray = field(repr=False, default_factory=lambda: np.zeros((0, 32), np.uint8))
    #: (earlier keyframe id, ``T_earlier_this``) measured by dense alignment, a bundle-adjustment factor; set for
    #: keyframes made where features failed (they share no landmarks with the map) and with ``dense_ba_factor``
    anchor: tuple[int, np.ndarray] | None = field(repr=False, default=None)


class _Growable:
    """Named numpy columns that grow by doubling (append-only rows)."""

    def __init__(self, **columns: tuple[tuple[int, ...], type, object]) -> None:
        self._spec = columns
        self.n = 0
        self._cap = 1024
        for name, (shape, dtype, fill) in columns.items():
            setattr(self, "_" + name, np.full((self._cap, *shape), fill, dtype))

    def _append(self, count: int, **values: np.ndarray) -> np.ndarray:
        if self.n + count > self._cap:
            cap = max(self._cap * 2, self.n + count)
            for name, (shape, dtype, fill) in self._spec.items():
                old = getattr(self, "_" + name)
                new = np.full((cap, *shape), fill, dtype)
                new[: self.n] = old[: self.n]
                setattr(self, "_" + name, new)
            self._cap = cap
        for name, value in values.items():
            getattr(self, "_" + name)[self.n: self.n + count] = value
        ids = np.arange(self.n, self.n + count)
        self.n += count
        return ids

    def col(self, name: str) -> np.ndarray:
        """Live view of the used rows of a column (writes go through)."""
        return getattr(self, "_" + name)[: self.n]


class Landmarks(_Growable):
    """3D points with a representative descriptor and found/visible counters (for culling)."""

    def __init__(self) -> None:
        super().__init__(pos=((3,), np.float64, 0.0), desc=((32,), np.uint8, 0), ref_kf=((), np.int64, -1),
                         visible=((), np.int32, 0), found=((), np.int32, 0), alive=((), bool, False),
                         first_kf=((), np.int64, -1))

    def add(self, pos: np.ndarray, desc: np.ndarray, kf_id: int) -> np.ndarray:
        return self._append(len(pos), pos=pos, desc=desc, ref_kf=kf_id, visible=1, found=1, alive=True,
                            first_kf=kf_id)

    @property
    def pos(self) -> np.ndarray:
        return self.col("pos")

    @property
    def desc(self) -> np.ndarray:
        return self.col("desc")

    @property
    def alive(self) -> np.ndarray:
        return self.col("alive")


class Observations(_Growable):
    """Which keyframe keypoint observes which landmark; rows are invalidated, never deleted."""

    def __init__(self) -> None:
        super().__init__(kf=((), np.int64, -1), kp=((), np.int64, -1), lm=((), np.int64, -1),
                         valid=((), bool, False))

    def add(self, kf_id: int, kp: np.ndarray, lm: np.ndarray) -> None:
        self._append(len(kp), kf=kf_id, kp=kp, lm=lm, valid=True)


class SlamMap:
    """Keyframes, landmarks and observations, with covisibility queries."""

    def __init__(self) -> None:
        self.keyframes: list[Keyframe] = []
        self.landmarks = Landmarks()
        self.obs = Observations()

    def add_keyframe(self, kf: Keyframe) -> None:
        """Register ``kf`` and its landmark observations."""
        self.keyframes.append(kf)
        kp = np.flatnonzero(kf.lm >= 0)
        self.obs.add(kf.id, kp, kf.lm[kp])

    def live_obs(self) -> np.ndarray:
        """Indices of valid observations of live landmarks."""
        valid = self.obs.col("valid")
        lm = self.obs.col("lm")
        return np.flatnonzero(valid & self.landmarks.alive[np.maximum(lm, 0)])

    def covisibility(self, kf_id: int) -> np.ndarray:
        """Number of landmarks each keyframe shares with ``kf_id`` (0 for itself)."""
        kf = self.keyframes[kf_id]
        mine = kf.lm[kf.lm >= 0]
        mine = mine[self.landmarks.alive[mine]]
        rows = self.live_obs()
        lm = self.obs.col("lm")[rows]
        hit = np.isin(lm, mine)
        counts = np.bincount(self.obs.col("kf")[rows][hit], minlength=len(self.keyframes))
        counts[kf_id] = 0
        return counts

    def covisible(self, kf_id: int, n: int, min_shared: int = 1) -> np.ndarray:
        """Up to ``n`` keyframes sharing the most landmarks with ``kf_id`` (at least ``min_shared``)."""
        counts = self.covisibility(kf_id)
        order = np.argsort(-counts, kind="stable")[:n]
        return order[counts[order] >= min_shared]

    def landmarks_of(self, kf_ids: np.ndarray) -> np.ndarray:
        """Live landmarks observed by any of ``kf_ids`` (sorted, unique)."""
        if len(kf_ids) == 0:
            return np.zeros(0, np.int64)
        ids = np.concatenate([self.keyframes[int(k)].lm for k in kf_ids])
        ids = np.unique(ids[ids >= 0])
        return ids[self.landmarks.alive[ids]]

    def drop_observations(self, rows: np.ndarray) -> None:
        """Forget observation ``rows`` (bundle-adjustment outliers) in the table and in their keyframes."""
        kfs = self.obs.col("kf")[rows]
        kps = self.obs.col("kp")[rows]
        self.obs.col("valid")[rows] = False
        for k in np.unique(kfs):
            self.keyframes[int(k)].lm[kps[kfs == k]] = -1

    def kf_poses(self) -> np.ndarray:
        """(K, 4, 4) current keyframe poses ``T_world_cam``."""
        return np.array([kf.T_wc for kf in self.keyframes])
