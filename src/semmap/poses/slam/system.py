"""The SLAM system: per-frame tracking, keyframe insertion with local bundle adjustment, loop closure and
relocalisation, and the final trajectory (every tracked frame relative to its reference keyframe)."""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field

import numpy as np

from semmap.errors import ConfigError, DatasetError
from semmap.poses.dense_align import DenseAligner
from semmap.poses.odometry import OdometryConfig
from semmap.poses.slam.config import SlamConfig
from semmap.poses.slam.features import VIRTUAL_BASELINE, FrameFeatures, OrbExtractor
from semmap.poses.slam.keyframes import create_keyframe, cull_landmarks, need_keyframe
from semmap.poses.slam.loop_closure import LoopCloser
from semmap.poses.slam.optimisation import BundleAdjuster
from semmap.poses.slam.pose_solver import PinholeModel
from semmap.poses.slam.relocalisation import relocalise
from semmap.poses.slam.tracking import LocalMapTracker, TrackResult
from semmap.poses.slam.world_map import SlamMap
from semmap.types import CameraIntrinsics, Frame, Trajectory, invert_pose, pose_change

log = logging.getLogger("semmap")

#: keypoints with depth a first frame needs to start the map
MIN_INIT_POINTS = 50


@dataclass
class SlamStats:
    """Counters and timings of a run (for reports and benchmarks)."""

    frames: int = 0
    tracked: int = 0
    lost: int = 0
    relocalisations: int = 0
    dense_fallbacks: int = 0  #: frames posed by dense alignment because feature tracking failed
    dense_refined: int = 0  #: feature-tracked poses refined by dense alignment
    loops: int = 0
    keyframes: int = 0
    track_s: float = 0.0  #: seconds in per-frame tracking (features, matching, PnP, refinement)
    mapping_s: float = 0.0  #: seconds in keyframe work (landmarks, bundle adjustment, loop closure)
    final_ba_s: float = 0.0  #: seconds in the final global bundle adjustment (``trajectory``)
    loop_frames: list[int] = field(default_factory=list)


class RgbdSlam:
    """Feature-based RGB-D SLAM (ORB features, local map tracking, local BA, loop closure, relocalisation).

    With the default settings every feature-tracked pose is refined by dense photometric + geometric alignment
    to its reference keyframe (``dense_refine``), keyframes are tied to their reference keyframe by that dense
    relative pose in bundle adjustment, and a frame that features cannot track (a textureless view) is posed by
    dense alignment and made a keyframe, so tracking continues from it (``dense_fallback``).

    ``track`` returns ``T_world_cam`` of each frame, or None while tracking is lost (lost frames are left out of
    ``trajectory``; later frames are relocalised against the keyframes). The first frame with enough keypoints
    with depth is the world origin.
    """

    name = "slam-orb"

    def __init__(self, config: SlamConfig | None = None) -> None:
        config = SlamConfig() if config is None else config
        if not isinstance(config, SlamConfig):
            raise ConfigError(f"RgbdSlam needs a SlamConfig, got {type(config).__name__}")
        self.config = config
        self.stats = SlamStats()
        self.map = SlamMap()
        self._intr: CameraIntrinsics | None = None
        # trajectory log: frame name, timestamp, reference keyframe, pose relative to it
        self._names: list[str] = []
        self._stamps: list[float] = []
        self._ref: list[int] = []
        self._rel: list[np.ndarray] = []
        self._last_stamp = -np.inf
        self._T_wc_last: np.ndarray | None = None
        self._velocity: np.ndarray | None = None  # T_last_current of the previous step
        self._ref_kf = -1
        self._since_kf = 0
        self._ref_inliers = 0
        self._lost = False
        self._global_ba_at = -1  # frame count at the last final bundle adjustment
        self._last_lm = np.zeros(0, np.int64)  # landmarks the last tracked frame matched
        self.dense: DenseAligner | None = None
        self._kf_images: dict[int, object] = {}  # keyframe id -> dense image (the newest few keyframes)
        self._last_image: object | None = None  # dense image of the last tracked frame

    # ------------------------------------------------------------------ setup
    def _setup(self, intr: CameraIntrinsics) -> None:
        cfg = self.config
        self._intr = intr
        self.extractor = OrbExtractor(cfg, intr)
        self.cam = PinholeModel(intr.fx, intr.fy, intr.cx, intr.cy, VIRTUAL_BASELINE * intr.fx)
        sigma = cfg.scale_factor ** np.arange(cfg.n_levels)
        self.tracker = LocalMapTracker(self.map, self.cam, (intr.width, intr.height), cfg, 1.0 / sigma**2,
                                       self.cam.bf * cfg.depth_noise)
        anchor_sigma = (np.radians(cfg.dense_sigma_deg), cfg.dense_sigma)
        self.ba = BundleAdjuster(self.cam, sigma, self.tracker.disp_sigma, cfg.ba_window, cfg.ba_iterations,
                                 anchor_sigma=anchor_sigma)
        if cfg.dense_fallback or cfg.dense_refine != "off":
            dense = OdometryConfig(iterations=tuple(cfg.dense_iterations), robust_iterations=(),
                                   depth_max=cfg.max_depth)
            self.dense = dense.aligner(intr, cfg.dense_scale)
        self.loops = LoopCloser(self.map, self.tracker, cfg)

    def _check(self, frame: Frame) -> None:
        if not isinstance(frame, Frame):
            raise DatasetError(f"RgbdSlam.track needs a semmap Frame, got {type(frame).__name__}")
        if self._intr is not None and frame.intrinsics != self._intr:
            raise DatasetError(f"frame {frame.name or frame.index}: intrinsics {frame.intrinsics} differ from the "
                               f"first frame's {self._intr}")
        if not frame.timestamp > self._last_stamp:
            raise DatasetError(f"frame {frame.name or frame.index}: timestamp {frame.timestamp} does not follow "
                               f"the previous frame's {self._last_stamp}")

    # ------------------------------------------------------------------ per frame
    def track(self, frame: Frame) -> np.ndarray | None:
        """``T_world_cam`` of ``frame``, or None when it cannot be tracked (see the class docstring)."""
        self._check(frame)
        if self._intr is None:
            self._setup(frame.intrinsics)
        self._last_stamp = frame.timestamp
        self.stats.frames += 1
        t0 = time.perf_counter()
        depth = np.nan_to_num(frame.depth, nan=0.0, posinf=0.0, neginf=0.0)
        feats = self.extractor.extract(frame.rgb, depth)
        image = self.dense.image(frame.rgb, depth) if self.dense is not None else None
        if not self.map.keyframes:
            return self._initialise(frame, feats, t0, image)
        res = self._track_frame(feats)
        if res is None and image is not None and self.config.dense_fallback and not self._lost:
            T_wc = self._dense_fallback(image)
            if T_wc is not None:
                return self._bridge(frame, feats, image, T_wc, t0)
        if res is None:
            self.stats.lost += 1
            self.stats.track_s += time.perf_counter() - t0
            if not self._lost:
                log.debug("slam: tracking lost at frame %s", frame.name or frame.index)
            self._lost = True
            self._velocity = None
            return None
        T_wc = invert_pose(res.T_cw)
        self._last_image = image
        lms = self.map.landmarks
        lms.col("visible")[res.n_visible_lm] += 1
        lms.col("found")[res.lm] += 1
        self._last_lm = res.lm
        self._since_kf += 1
        if self._since_kf == 1:
            self._ref_inliers = max(self._ref_inliers, res.n_inliers)
        keyframe = need_keyframe(self.config, feats, res, self._since_kf, self._ref_inliers)
        anchor = None
        refine = self.config.dense_refine
        if image is not None and (refine == "frames" or (refine == "keyframes" and keyframe)):
            T_wc, anchor = self._dense_refine(image, T_wc)
        if self._T_wc_last is not None and not self._lost:
            self._velocity = invert_pose(self._T_wc_last) @ T_wc
        self._lost = False
        self._T_wc_last = T_wc
        t1 = time.perf_counter()
        self.stats.track_s += t1 - t0
        if keyframe:
            T_wc = self._insert_keyframe(feats, T_wc, res, image, anchor if self.config.dense_ba_factor else None)
            self.stats.mapping_s += time.perf_counter() - t1
        else:
            self._log_frame(frame, T_wc)
            return T_wc
        self._log_frame(frame, T_wc, keyframe=True)
        return T_wc

    def _initialise(self, frame: Frame, feats: FrameFeatures, t0: float, image: object | None) -> np.ndarray | None:
        if int(feats.has_depth.sum()) < MIN_INIT_POINTS:
            self.stats.lost += 1
            return None
        T = np.eye(4)
        kf = create_keyframe(self.map, self.config, feats, T, len(self._names), np.zeros(0, np.int64),
                             np.zeros(0, np.int64))
        self.tracker.set_local_map(np.array([kf.id]))
        self._keep_image(kf.id, image)
        self._last_image = image
        self._ref_kf, self._since_kf, self._ref_inliers = kf.id, 0, 0
        self._T_wc_last, self._velocity = T, None
        self.stats.keyframes += 1
        self.stats.track_s += time.perf_counter() - t0
        self._log_frame(frame, T, keyframe=True)
        return T

    def _track_frame(self, feats: FrameFeatures) -> TrackResult | None:
        """Track with the motion model, then without it and a wider search, then relocalise."""
        if not self._lost and self._T_wc_last is not None:
            last = invert_pose(self._T_wc_last)
            if self._velocity is not None:
                res = self.tracker.track(feats, invert_pose(self._T_wc_last @ self._velocity),
                                         first_ids=self._last_lm)
                if res is not None:
                    return res
            res = self.tracker.track(feats, last, radius_scale=3.0)
            if res is not None:
                return res
        found = relocalise(self.map, self.tracker, feats, self.config, seed=self.stats.frames)
        if found is None:
            return None
        res, kf_id = found
        self.stats.relocalisations += 1
        self._ref_kf = kf_id
        self._set_local_map(kf_id)
        return res

    def _set_local_map(self, kf_id: int) -> None:
        """Local map: the reference keyframe, its covisible keyframes and the most recent ones."""
        cfg = self.config
        recent = np.arange(max(0, len(self.map.keyframes) - 3), len(self.map.keyframes))
        ids = np.unique(np.concatenate([[kf_id], self.map.covisible(kf_id, cfg.covisible_keyframes), recent]))
        self.tracker.set_local_map(ids)

    # ------------------------------------------------------------------ keyframes
    def _insert_keyframe(self, feats: FrameFeatures, T_wc: np.ndarray, res: TrackResult | None,
                         image: object | None = None, anchor: tuple[int, np.ndarray] | None = None) -> np.ndarray:
        """Make the frame a keyframe, refine the local map, look for a loop; returns the frame's revised pose.

        ``res`` None: a keyframe posed without feature matches (dense fallback), every keypoint with depth is new.
        """
        cfg = self.config
        kp, lm = (res.kp, res.lm) if res is not None else (np.zeros(0, np.int64), np.zeros(0, np.int64))
        kf = create_keyframe(self.map, cfg, feats, T_wc, len(self._names), kp, lm)
        kf.anchor = anchor
        self._keep_image(kf.id, image)
        self.stats.keyframes += 1
        if cfg.local_ba and kf.id >= 2:
            self.ba.run(self.map, kf.id)
        cull_landmarks(self.map, cfg, kf.id)
        if cfg.loop_closure and res is not None:
            found = self.loops.detect(kf)
            if found is not None:
                loop_kf, loop_res = found
                self.loops.close(kf, loop_kf, loop_res)
                self.stats.loops += 1
                self.stats.loop_frames.append(len(self._names))
                log.debug("slam: loop closed between keyframes %d and %d", kf.id, loop_kf)
        self._ref_kf, self._since_kf, self._ref_inliers = kf.id, 0, 0
        self._set_local_map(kf.id)
        new_T = kf.T_wc.copy()
        self._T_wc_last = new_T
        return new_T

    # ------------------------------------------------------------------ dense alignment
    def _keep_image(self, kf_id: int, image: object | None) -> None:
        """Remember a keyframe's dense image (only the newest few are kept: the reference is nearly always one)."""
        if image is None:
            return
        self._kf_images[kf_id] = image
        for old in [k for k in self._kf_images if k <= kf_id - 4]:
            del self._kf_images[old]

    def _dense_refine(self, image: object, T_wc: np.ndarray) -> tuple[np.ndarray, tuple[int, np.ndarray] | None]:
        """``T_wc`` refined by dense alignment to the reference keyframe (unchanged when that is not possible or
        disagrees too much), and the keyframe-relative pose as an anchor (None when not refined)."""
        cfg = self.config
        ref_image = self._kf_images.get(self._ref_kf)
        if ref_image is None:
            return T_wc, None
        T_ref = self.map.keyframes[self._ref_kf].T_wc
        init = invert_pose(T_ref) @ T_wc
        out = self.dense.align(image, ref_image, init)
        if out is None or out.fitness < cfg.dense_min_fitness:
            return T_wc, None
        dist, angle = pose_change(init, out.T)
        if dist > cfg.dense_max_correction or angle > cfg.dense_max_correction_deg:
            return T_wc, None
        self.stats.dense_refined += 1
        return T_ref @ out.T, (self._ref_kf, out.T)

    def _dense_fallback(self, image: object) -> np.ndarray | None:
        """Pose of a frame that features could not track, by dense alignment to the reference keyframe, else to
        the last tracked frame, from the constant-velocity prediction; None when neither agrees."""
        cfg = self.config
        predicted = self._T_wc_last @ self._velocity if self._velocity is not None else self._T_wc_last
        targets = []
        if self._ref_kf in self._kf_images:
            targets.append((self._kf_images[self._ref_kf], self.map.keyframes[self._ref_kf].T_wc))
        if self._last_image is not None:
            targets.append((self._last_image, self._T_wc_last))
        for target, T_target in targets:
            out = self.dense.align(image, target, invert_pose(T_target) @ predicted)
            if out is None or out.fitness < cfg.dense_min_fitness:
                continue
            T_wc = T_target @ out.T
            dist, angle = pose_change(predicted, T_wc)
            if dist <= cfg.dense_max_jump and angle <= cfg.dense_max_jump_deg:
                return T_wc
        return None

    def _bridge(self, frame: Frame, feats: FrameFeatures, image: object, T_wc: np.ndarray,
                t0: float) -> np.ndarray:
        """Keep tracking through a frame posed by dense alignment only: it becomes a keyframe (tied to the previous
        reference keyframe by a relative-pose factor) whose keypoints start fresh landmarks, so feature tracking
        resumes from it."""
        self.stats.dense_fallbacks += 1
        if self._T_wc_last is not None:
            self._velocity = invert_pose(self._T_wc_last) @ T_wc
        self._T_wc_last = T_wc
        self._last_image = image
        self._last_lm = np.zeros(0, np.int64)
        t1 = time.perf_counter()
        self.stats.track_s += t1 - t0
        anchor = (self._ref_kf, invert_pose(self.map.keyframes[self._ref_kf].T_wc) @ T_wc)
        T_wc = self._insert_keyframe(feats, T_wc, None, image, anchor)
        self.stats.mapping_s += time.perf_counter() - t1
        self._log_frame(frame, T_wc, keyframe=True)
        return T_wc

    # ------------------------------------------------------------------ output
    def _log_frame(self, frame: Frame, T_wc: np.ndarray, keyframe: bool = False) -> None:
        ref = len(self.map.keyframes) - 1 if keyframe else self._ref_kf
        self._names.append(frame.name or str(frame.index))
        self._stamps.append(float(frame.timestamp))
        self._ref.append(ref)
        self._rel.append(invert_pose(self.map.keyframes[ref].T_wc) @ T_wc)
        self.stats.tracked += 1

    def trajectory(self) -> Trajectory:
        """Optimised ``T_world_cam`` of every tracked frame: its reference keyframe's final pose (after one global
        bundle adjustment, unless disabled) times the frame's pose relative to it."""
        if not self._names:
            return Trajectory(np.zeros(0), np.zeros((0, 4, 4)), ())
        if self.config.global_ba and self._global_ba_at != len(self._names):
            t0 = time.perf_counter()
            self.ba.run_global(self.map, self.config.global_ba_iterations)
            self._global_ba_at = len(self._names)
            self.stats.final_ba_s += time.perf_counter() - t0
        kf_poses = self.map.kf_poses()
        poses = kf_poses[np.array(self._ref)] @ np.array(self._rel)
        return Trajectory(np.array(self._stamps), poses, tuple(self._names))
