"""Dense RGB-D odometry (multi-scale photometric + geometric Gauss-Newton alignment) as a PoseTracker.

Each frame is aligned to a reference frame, starting from a constant-velocity prediction; each frame's image
pyramids are built once (:mod:`semmap.poses.dense_align`), so a keyframe's serve every frame aligned to it.
The reference is a keyframe that is replaced once the camera has moved far enough from it (or every frame, with
``reference="frame"``). A rejected alignment (low fitness, a non-finite or implausible jump) falls back to
the motion model and is flagged in :attr:`DenseOdometry.fallbacks`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from semmap.errors import ConfigError
from semmap.poses.dense_align import METHODS, DenseAligner, DenseImage, check_schedule
from semmap.types import CameraIntrinsics, Frame, Trajectory, invert_pose, pose_change, snap_rigid


@dataclass(frozen=True)
class OdometryConfig:
    """Settings of :class:`DenseOdometry`; the defaults are the variant that measured best (see the benchmark)."""

    #: Cost: "hybrid" (photometric + geometric), "intensity" or "point_to_plane".
    method: str = "hybrid"
    #: Gauss-Newton iterations per pyramid level, coarse to fine, with the wide intensity Huber width
    #: (``intensity_huber_delta``) ...
    iterations: tuple[int, ...] = (10, 5, 1)
    #: ... then these per level with the narrow one. The wide width converges from the motion model's guess; the
    #: narrow one (about twice the robust spread of 7-Scenes' intensity residuals) then keeps view-dependent
    #: brightness from biasing the pose: with the wide width alone 7-Scenes rotations came out 5 % short of the
    #: ground truth's and the ATE 3.02 cm; with robust steps at 0.02 it is 2.5-2.7 cm, the simulations unchanged.
    #: One robust full-resolution step: with the own kernels a second measured no better (7-Scenes 2.60 against
    #: 2.52 cm) and cost a quarter of the frame time (see DESIGN). Empty: none.
    robust_iterations: tuple[int, ...] = (0, 3, 1)
    robust_intensity_huber_delta: float = 0.02
    #: Weight of the depth residual (metres) against the intensity one (in [0, 1]) in the hybrid cost.
    depth_weight: float = 2.0
    #: Depth beyond this (metres) is ignored.
    depth_max: float = 4.0
    #: Loss parameters: depth outlier cut-off and Huber widths (metres, intensity in [0, 1]).
    depth_outlier_trunc: float = 0.07
    depth_huber_delta: float = 0.05
    intensity_huber_delta: float = 0.1
    #: "keyframe" (frame to keyframe) or "frame" (frame to previous frame).
    reference: str = "keyframe"
    #: Start each alignment from a constant-velocity prediction (else from the previous pose).
    motion_model: bool = True
    #: A new keyframe once the camera is this far from the current one (metres, degrees) ...
    keyframe_distance: float = 0.10
    keyframe_angle_deg: float = 8.0
    #: ... or when the alignment fitness (fraction of pixels with a correspondence) drops below this.
    keyframe_fitness: float = 0.6
    #: An alignment with lower fitness is rejected (motion-model fallback).
    min_fitness: float = 0.2
    #: An alignment this far from the prediction (metres, degrees) is rejected as a jump.
    max_jump: float = 0.25
    max_jump_deg: float = 20.0

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise ConfigError(f"odometry method must be one of {', '.join(METHODS)}, got {self.method!r}")
        if self.reference not in ("keyframe", "frame"):
            raise ConfigError(f"odometry reference must be 'keyframe' or 'frame', got {self.reference!r}")
        check_schedule(self.iterations, self.robust_iterations)  # here already, not at the first frame
        if not self.depth_max > 0:
            raise ConfigError(f"odometry depth_max must be positive, got {self.depth_max}")

    def aligner(self, intrinsics: CameraIntrinsics, scale: int = 1) -> DenseAligner:
        """The dense aligner these settings describe, for images of ``intrinsics`` subsampled by ``scale``."""
        return DenseAligner(intrinsics, iterations=tuple(self.iterations), depth_max=self.depth_max,
                            loss=(self.depth_outlier_trunc, self.depth_huber_delta, self.intensity_huber_delta),
                            method=self.method, scale=scale, robust_iterations=tuple(self.robust_iterations),
                            robust_intensity_huber=self.robust_intensity_huber_delta, depth_weight=self.depth_weight)


@dataclass(frozen=True)
class FrameReport:
    """What happened to one frame: alignment quality, fallback, keyframe."""

    name: str
    fitness: float
    inlier_rmse: float
    fallback: str = ""  # why the motion model was used instead ("" when aligned)
    keyframe: bool = False


@dataclass
class Reference:
    """The frame the next one is aligned to."""

    image: DenseImage
    pose: np.ndarray


class DenseOdometry:
    """Frame-to-keyframe (or frame-to-frame) dense RGB-D odometry; the first frame defines the world."""

    name = "odometry"

    def __init__(self, config: OdometryConfig | None = None) -> None:
        self.config = config or OdometryConfig()
        self._aligner: DenseAligner | None = None
        self._ref: Reference | None = None
        self._stamps: list[float] = []
        self._poses: list[np.ndarray] = []
        self._names: list[str] = []
        self.reports: list[FrameReport] = []

    @property
    def fallbacks(self) -> list[FrameReport]:
        """Frames whose pose came from the motion model because the alignment was rejected."""
        return [r for r in self.reports if r.fallback]

    def track(self, frame: Frame) -> np.ndarray:
        """Pose of ``frame`` (always one: a failed alignment falls back to the motion model)."""
        if self._aligner is None:
            self._aligner = self.config.aligner(frame.intrinsics)
        image = self._aligner.image(frame.rgb, frame.depth)
        name = frame.name or str(frame.index)
        if self._ref is None:
            pose = np.eye(4)
            self._set_reference(frame, image, pose)
            self._record(frame, name, pose, FrameReport(name, 1.0, 0.0, keyframe=True))
            return pose

        predicted = self._predict()
        pose, fitness, rmse, reason = self._align(image, self._ref, predicted)
        recovered = None
        if reason:
            recovered = self._recover(frame, image, predicted)
            pose = predicted if recovered is None else recovered
            if recovered is not None:
                reason = ""
        new_keyframe = recovered is not None or self._wants_keyframe(pose, fitness, reason)
        if new_keyframe:
            self._set_reference(frame, image, pose)
        self._record(frame, name, pose, FrameReport(name, fitness, rmse, reason, new_keyframe))
        return pose

    def _align(self, image: DenseImage, ref: Reference,
               predicted: np.ndarray) -> tuple[np.ndarray, float, float, str]:
        """(pose, fitness, inlier RMSE, why it is rejected or "") of ``image`` aligned to ``ref`` from a prediction."""
        result = self._aligner.align(image, ref.image, invert_pose(ref.pose) @ predicted)
        if result is None:  # a singular system ("tracking failed") or a non-finite result
            return predicted, 0.0, float("nan"), "dense alignment failed (too little valid depth or texture)"
        pose = snap_rigid(ref.pose @ result.T)
        return pose, result.fitness, result.inlier_rmse, self._reject(pose, predicted, result.fitness)

    def _set_reference(self, frame: Frame, image: DenseImage, pose: np.ndarray) -> None:
        """Make ``frame`` (about to be recorded at ``pose``) the keyframe the next frames are aligned to."""
        self._ref = Reference(image, pose)

    def _recover(self, frame: Frame, image: DenseImage, predicted: np.ndarray) -> np.ndarray | None:
        """A pose for a frame whose alignment was rejected, or None for the motion-model fallback (a hook for
        trackers that can relocalise; the frame then becomes a keyframe)."""
        return None

    def _predict(self) -> np.ndarray:
        """Constant-velocity prediction of the next pose (the last pose without a motion model)."""
        last = self._poses[-1]
        if not self.config.motion_model or len(self._poses) < 2:
            return last
        return snap_rigid(last @ (invert_pose(self._poses[-2]) @ last))

    def _reject(self, pose: np.ndarray, predicted: np.ndarray, fitness: float) -> str:
        """Why an alignment result is not trusted ("" when it is)."""
        c = self.config
        if not np.isfinite(pose).all():
            return "non-finite transformation"
        if fitness < c.min_fitness:
            return f"fitness {fitness:.2f} < {c.min_fitness}"
        dist, angle = pose_change(predicted, pose)
        if dist > c.max_jump or angle > c.max_jump_deg:
            return f"jump of {dist:.2f} m / {angle:.1f} deg from the prediction"
        return ""

    def _wants_keyframe(self, pose: np.ndarray, fitness: float, fallback: str) -> bool:
        """Whether the current frame becomes the new reference."""
        c = self.config
        if c.reference == "frame":
            return True
        if fallback:
            # Keep the old reference after a single failure; start afresh if two in a row failed.
            return bool(self.reports) and bool(self.reports[-1].fallback)
        dist, angle = pose_change(self._ref.pose, pose)
        return dist > c.keyframe_distance or angle > c.keyframe_angle_deg or fitness < c.keyframe_fitness

    def _record(self, frame: Frame, name: str, pose: np.ndarray, report: FrameReport) -> None:
        self._stamps.append(frame.timestamp)
        self._poses.append(pose)
        self._names.append(name)
        self.reports.append(report)

    def trajectory(self) -> Trajectory:
        """Poses of every frame seen so far (odometry never revises them)."""
        return Trajectory(np.asarray(self._stamps), np.asarray(self._poses).reshape(-1, 4, 4), tuple(self._names))

