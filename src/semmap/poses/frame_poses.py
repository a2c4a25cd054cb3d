"""The pose of each frame of a run from one source, and the trajectories a run reports: the poses it mapped with
and the frames' own ground truth."""

from __future__ import annotations

import time

import numpy as np

from semmap.poses.base import LiveTracker, PoseTracker
from semmap.poses.file import GroundTruthRecorder
from semmap.types import Frame, Trajectory


class FramePoses:
    """Pose of each frame from one source (ground truth, a trajectory lookup or a tracker's poses by frame
    name); remembers the poses used and the frames' own ground truth, for ``trajectory.txt`` and its score."""

    def __init__(self, source: str, *, by_name: dict[str, np.ndarray] | None = None, lookup=None,
                 tracking_s: float | None = None, tracked: int = 0, tracker: PoseTracker | None = None,
                 edge_stats: dict | None = None):
        self.source, self.by_name, self.lookup = source, by_name, lookup
        self.tracking_s, self.tracked = tracking_s, tracked
        self.edge_stats = edge_stats  # what object constraints did to the trajectory (X-objects trackers)
        self.tracker = tracker  # online: tracked frame by frame, as the frames arrive
        self._used: list[tuple[float, str, np.ndarray]] = []
        self._gt = GroundTruthRecorder()
        self.reach_m: float | None = None  # a camera farther from the origin adds nothing to a map: no pose
        self.beyond_reach = 0  # frames given no pose for that
        self.transform: np.ndarray | None = None  # --continue: the source's frame in the prior map's (T_prior_seq)

    def limit_to(self, reach_m: float) -> None:
        """Give no pose to a frame whose camera lies ``reach_m`` or more from the origin (what the maps can hold):
        such a frame is skipped with a warning naming it, instead of adding nothing or overflowing a kernel."""
        self.reach_m = float(reach_m)

    def source_pose(self, frame: Frame) -> tuple[np.ndarray | None, str]:
        """(pose in the source's own frame or None, why not), recording nothing (not for online trackers)."""
        if self.by_name is not None:
            T = self.by_name.get(frame.name)
            return T, "" if T is not None else f"{self.source} tracking lost"
        if self.lookup is not None:
            found = self.lookup.pose_of(frame)
            return found.pose, found.reason
        return frame.T_world_cam, "no ground-truth pose"

    def __call__(self, frame: Frame) -> tuple[np.ndarray | None, str]:
        """(pose or None, why not); in the prior map's frame when the run continues one (``transform``)."""
        if self.tracker is not None:
            T, reason = self._track(frame), f"{self.source} tracking lost"
        else:
            T, reason = self.source_pose(frame)
        if T is not None and self.transform is not None:
            T = self.transform @ np.asarray(T, np.float64)
        if T is not None and self.reach_m is not None:
            far = float(np.abs(np.asarray(T)[:3, 3]).max())
            if far >= self.reach_m:
                self.beyond_reach += 1
                T, reason = None, (f"its camera lies {far:,.0f} m from the origin, beyond the ±{self.reach_m:,.0f} m "
                                   "the maps can hold at this resolution")
        if frame.T_world_cam is None or self.reach_m is None or np.abs(frame.T_world_cam[:3, 3]).max() < self.reach_m:
            self._gt.add(frame)  # (ground truth that far away is left out of the score too)
        if T is not None:
            self._used.append((frame.timestamp, frame.name, T))
        return T, reason

    def _track(self, frame: Frame) -> np.ndarray | None:
        """The tracker's pose of a new frame, through its latest global optimisation where it has one."""
        t0 = time.perf_counter()
        T = self.tracker.track(frame)
        if T is not None and isinstance(self.tracker, LiveTracker):
            T = self.tracker.live_pose()
        self.tracking_s = (self.tracking_s or 0.0) + time.perf_counter() - t0
        self.tracked += T is not None
        return None if T is None else np.array(T, np.float64)

    def used_trajectory(self) -> Trajectory:
        """The poses frames were mapped with, in time order."""
        return Trajectory.from_rows(self._used)

    def ground_truth(self) -> Trajectory:
        """The frames' own ground-truth poses, in time order."""
        return self._gt.trajectory()

    def state(self) -> tuple[dict, dict[str, np.ndarray]]:
        """A checkpoint's pose source (offline): its JSON-able fields and its arrays (poses by frame name, the poses
        used and the ground truth so far). A tracker's state is not saved: online runs take no checkpoints."""
        names = [] if self.by_name is None else list(self.by_name)
        meta = {"source": self.source, "tracking_s": self.tracking_s, "tracked": self.tracked,
                "edge_stats": self.edge_stats, "by_name": None if self.by_name is None else names}
        arrays = {"by_name": _stack([self.by_name[n] for n in names])}
        for key, rows in (("used", self._used), ("ground_truth", self._gt.rows)):
            meta[key] = [[float(t), str(name)] for t, name, _ in rows]
            arrays[key] = _stack([T for _, _, T in rows])
        return meta, arrays

    def restore(self, meta: dict, arrays: dict[str, np.ndarray]) -> None:
        """Continue from :meth:`state` (on a pose source of the same kind, its file lookup rebuilt)."""
        if meta.get("by_name") is not None:
            self.by_name = dict(zip(meta["by_name"], _poses(arrays, "by_name", len(meta["by_name"])), strict=True))
        self.tracking_s, self.tracked, self.edge_stats = meta["tracking_s"], int(meta["tracked"]), meta["edge_stats"]
        self._used = [(float(t), str(name), T) for (t, name), T in
                      zip(meta["used"], _poses(arrays, "used", len(meta["used"])), strict=True)]
        truth = meta["ground_truth"]
        self._gt.extend((t, name, T) for (t, name), T in
                        zip(truth, _poses(arrays, "ground_truth", len(truth)), strict=True))

def _stack(poses: list[np.ndarray]) -> np.ndarray:
    return np.asarray(poses, np.float64).reshape(-1, 4, 4)


def _poses(arrays: dict[str, np.ndarray], name: str, n: int) -> np.ndarray:
    """``n`` poses of a checkpoint's array ``name``, or a FormatError."""
    from semmap.errors import FormatError

    poses = arrays.get(name)
    if poses is None or poses.shape != (n, 4, 4):
        raise FormatError(f"checkpoint of the pose source: {name} holds {None if poses is None else poses.shape}, "
                          f"expected ({n}, 4, 4)")
    return np.asarray(poses, np.float64)
