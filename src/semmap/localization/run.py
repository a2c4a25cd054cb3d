"""A localization run over a sequence: per frame, the motion since the last update, the frame's scan, one filter
update, and the estimate scored against the frame's ground truth when it has one.

:func:`localize` is what ``semmap localize`` and ``benchmarks/bench_localization.py`` call; the result keeps
every estimate, the errors over time and thinned particle snapshots for the plots.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass, field
from enum import Enum

import numpy as np

from semmap.errors import ConfigError
from semmap.localization._kernels import compile_kernels
from semmap.localization.filter import FilterSettings, ParticleFilter, PoseEstimate
from semmap.localization.motion import GroundTilt, MotionSource
from semmap.localization.observation import DEFAULT_POINTS, make_scan
from semmap.localization.prior import PriorMap
from semmap.types import Frame, TopKProbs, Trajectory, invert_pose, pose_change

log = logging.getLogger("semmap")
#: Segmentation of a frame: (H, W, k) class sets or None.
SegmentFn = Callable[[Frame], TopKProbs | None]
#: Ground-mode height and tilt of a frame (None: not known for this frame).
TiltFn = Callable[[Frame], GroundTilt | None]
#: A run converged on the true pose when the error after convergence stays within these (else: false convergence).
TRUE_CONVERGENCE_M, TRUE_CONVERGENCE_DEG = 0.25, 10.0


class InitMode(str, Enum):
    """How the particles start."""

    GLOBAL = "global"  # uniformly over the map's free space: the robot does not know where it is
    TRACKING = "tracking"  # around a known starting pose


@dataclass
class UpdateRecord:
    """One filter update: the frame, the estimate, timings, and errors where the frame has ground truth."""

    index: int
    timestamp: float
    name: str
    estimate: PoseEstimate
    scan_points: int
    scan_ms: float
    segment_ms: float
    pos_err_m: float | None = None
    rot_err_deg: float | None = None


@dataclass
class LocalizationResult:
    """Every update of a run, the ground truth met on the way, and particle snapshots (update index -> (n, 4))."""

    settings: FilterSettings
    init: InitMode
    motion: str
    updates: list[UpdateRecord] = field(default_factory=list)
    snapshots: dict[int, np.ndarray] = field(default_factory=dict)
    ground_truth: dict[int, np.ndarray] = field(default_factory=dict)  # update index -> T_world_cam
    skipped: list[str] = field(default_factory=list)

    def trajectory(self) -> Trajectory:
        """The estimates as a trajectory (``localization.txt``)."""
        return Trajectory(np.array([u.timestamp for u in self.updates]),
                          np.array([u.estimate.T_world_cam for u in self.updates]).reshape(-1, 4, 4),
                          tuple(u.name for u in self.updates))

    def first_converged(self) -> int | None:
        """Index (into ``updates``) of the first update at which the filter reported convergence."""
        return next((i for i, u in enumerate(self.updates) if u.estimate.converged), None)

    def summary(self) -> dict:
        """Convergence, errors after convergence and timings (JSON-serialisable)."""
        ups = self.updates
        ms = np.array([u.estimate.ms["total"] for u in ups]) if ups else np.zeros(0)
        first = self.first_converged()
        out: dict = {"updates": len(ups), "particles": self.settings.particles, "model": self.settings.model.value,
                     "mode": self.settings.mode.value, "init": self.init.value, "motion": self.motion,
                     "frames_skipped": len(self.skipped),
                     "converged_at_end": bool(ups and ups[-1].estimate.converged),
                     "frames_to_converge": None if first is None else first + 1,
                     "seconds_to_converge": None if first is None
                     else round(ups[first].timestamp - ups[0].timestamp, 3),
                     "ms_per_update": _stats(ms),
                     "cpu_ms_per_update": _stats(np.array([u.estimate.ms.get("cpu", np.nan) for u in ups])),
                     "ms_per_scan": _stats(np.array([u.scan_ms for u in ups])),
                     "ms_per_segmentation": _stats(np.array([u.segment_ms for u in ups]))}
        errs = [(u.pos_err_m, u.rot_err_deg) for u in ups if u.pos_err_m is not None]
        if errs:
            after = [(u.pos_err_m, u.rot_err_deg) for u in ups[first or 0:] if u.pos_err_m is not None] \
                if first is not None else []
            out["pos_err_m_final"] = round(errs[-1][0], 4)
            out["rot_err_deg_final"] = round(errs[-1][1], 3)
            if after:
                p, r = np.array(after).T
                out["pos_err_m_after_convergence"] = {"median": round(float(np.median(p)), 4),
                                                      "mean": round(float(p.mean()), 4),
                                                      "max": round(float(p.max()), 4)}
                out["rot_err_deg_after_convergence"] = {"median": round(float(np.median(r)), 3),
                                                        "mean": round(float(r.mean()), 3),
                                                        "max": round(float(r.max()), 3)}
                out["converged_to_truth"] = bool(np.median(p) <= TRUE_CONVERGENCE_M
                                                 and np.median(r) <= TRUE_CONVERGENCE_DEG)
            else:
                out["converged_to_truth"] = False
        return out


def _stats(ms: np.ndarray) -> dict:
    if ms.size == 0:
        return {}
    return {"mean": round(float(ms.mean()), 2), "median": round(float(np.median(ms)), 2),
            "p95": round(float(np.percentile(ms, 95)), 2), "min": round(float(ms.min()), 2)}


def localize(prior: PriorMap, frames: Iterable[Frame], motion: MotionSource, *, settings: FilterSettings,
             init: InitMode = InitMode.GLOBAL, init_pose: np.ndarray | None = None,
             segment: SegmentFn | None = None, tilt_of: TiltFn | None = None, points: int = DEFAULT_POINTS,
             seed: int = 0, snapshot_every: int = 1, snapshot_particles: int = 2000,
             progress: Callable[[Iterator, int], Iterator] | None = None, total: int = 0) -> LocalizationResult:
    """Localize the camera of ``frames`` in ``prior``: one filter update per frame that the motion source (and in
    ground mode ``tilt_of``) has a pose for; ``init_pose`` (tracking) defaults to the first frame's ground truth."""
    compile_kernels()  # first-use compilation stays out of the timed updates
    pf = ParticleFilter(prior, settings, seed=seed)
    rng = np.random.default_rng([seed, 0x5CA])
    result = LocalizationResult(settings, init, motion.name)
    last_motion: np.ndarray | None = None
    it: Iterator[Frame] = iter(frames)
    if progress is not None:
        it = progress(it, total)
    for frame in it:
        pose = motion.pose(frame)
        tilt = tilt_of(frame) if (tilt_of is not None and pf.ground) else None
        if pose is None or (pf.ground and tilt is None):
            result.skipped.append(frame.name or str(frame.index))
            log.warning("frame %s: no %s, skipped", frame.name or frame.index,
                        "motion" if pose is None else "camera height and tilt")
            continue
        t0 = time.perf_counter()
        semantics = segment(frame) if segment is not None else None
        t1 = time.perf_counter()
        scan = make_scan(frame.depth, frame.intrinsics, semantics, resolution=prior.resolution, max_points=points,
                         rng=rng, num_classes=prior.num_classes)
        scan_ms, segment_ms = (time.perf_counter() - t1) * 1e3, (t1 - t0) * 1e3
        if not pf.initialised:
            _initialise(pf, init, init_pose, frame, tilt)
            u = np.eye(4)
        else:
            u = invert_pose(last_motion) @ pose
        last_motion = pose
        est = pf.step(u, scan, tilt)
        rec = UpdateRecord(frame.index, frame.timestamp, frame.name or f"{frame.timestamp:.6f}", est, len(scan),
                           scan_ms, segment_ms)
        k = len(result.updates)
        if frame.T_world_cam is not None:
            rec.pos_err_m, rec.rot_err_deg = pose_change(frame.T_world_cam, est.T_world_cam)
            result.ground_truth[k] = np.asarray(frame.T_world_cam, np.float64)
        result.updates.append(rec)
        if snapshot_every > 0 and k % snapshot_every == 0:
            result.snapshots[k] = pf.snapshot(snapshot_particles)
    if not result.updates:
        raise ConfigError("no frame could be used for localization (no motion poses"
                          + (" or camera heights" if pf.ground else "") + ")")
    last = len(result.updates) - 1
    if last not in result.snapshots:
        result.snapshots[last] = pf.snapshot(snapshot_particles)
    return result


def _initialise(pf: ParticleFilter, init: InitMode, init_pose: np.ndarray | None, frame: Frame,
                tilt: GroundTilt | None) -> None:
    if init == InitMode.GLOBAL:
        pf.init_global(tilt)
        return
    pose = init_pose if init_pose is not None else frame.T_world_cam
    if pose is None:
        raise ConfigError("tracking initialisation needs a starting pose (--init-pose) or ground truth on the "
                          "first frame")
    pf.init_tracking(pose, tilt)
