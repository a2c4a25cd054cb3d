"""``semmap localize MAP SEQ``: a recorded sequence localized in a map written by semmap, outputs written.

:func:`localize_sequence` wires the parts: the map's lookup grids, the dataset, the motion source (semmap's
odometry, a trajectory file, or the ground truth with drift), the segmenter giving each frame its class sets, the
ground-mode camera height and tilt, then :func:`~semmap.localization.run.localize` and the files.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from semmap.errors import ConfigError
from semmap.files.outputs import OutputKind, check_outputs
from semmap.files.safe import path_kind
from semmap.io.staged_run import write_staged
from semmap.limits import check, check_option
from semmap.localization.filter import FilterSettings
from semmap.localization.motion import (
    GroundTilt,
    MotionMode,
    MotionSource,
    NoisyGroundTruth,
    OdometrySource,
    TrajectorySource,
)
from semmap.localization.observation import DEFAULT_POINTS, ObservationKind
from semmap.localization.outputs import write_outputs
from semmap.localization.prior import load_prior
from semmap.localization.run import InitMode, LocalizationResult, localize
from semmap.types import Frame

log = logging.getLogger("semmap")
#: ``--motion`` values that are not a trajectory file.
MOTION_SOURCES = ("odometry", "gt-noisy")


@dataclass(frozen=True)
class LocalizeOptions:
    """What ``semmap localize`` was asked for (besides the map, the sequence and the output folder)."""

    settings: FilterSettings = field(default_factory=FilterSettings)
    init: InitMode = InitMode.GLOBAL
    init_pose: np.ndarray | None = None  # tracking: starting T_world_cam (default: the first frame's ground truth)
    motion: str = "odometry"  # odometry | gt-noisy | path of a TUM trajectory
    motion_noise: float = 0.05  # gt-noisy: drift as a fraction of each motion
    segmenter: str | None = "auto"  # auto | none | a segmenter (semmap.perception.registry.SEGMENTERS)
    weights: Path | None = None
    trust_weights: bool = False  # shipped weights whose sha256 differs from the manifest: used with a warning
    height: float | None = None  # ground mode without ground truth: camera height ...
    pitch_deg: float = 0.0  # ... and its fixed pitch and roll
    roll_deg: float = 0.0
    points: int = DEFAULT_POINTS
    stride: int = 1
    max_frames: int | None = None
    seed: int = 0
    gif: bool = False

    def __post_init__(self) -> None:
        """Refuse NaN, infinite or meaningless numbers here (the table of ``semmap.limits``), in one line, before
        any numba kernel sees them."""
        for option, value in (("--height", self.height), ("--pitch-deg", self.pitch_deg),
                              ("--roll-deg", self.roll_deg), ("--motion-noise", self.motion_noise),
                              ("--particles", self.settings.particles), ("--points", self.points),
                              ("--stride", self.stride), ("--max-frames", self.max_frames), ("--seed", self.seed)):
            check_option(option, value)
        if self.init_pose is not None:
            _check_pose(self.init_pose)


def _check_pose(pose: np.ndarray) -> None:
    """ConfigError unless ``pose`` is a finite rigid 4x4 transform (a zero or NaN quaternion gives NaN)."""
    T = np.asarray(pose, dtype=np.float64)
    if T.shape != (4, 4) or not np.isfinite(T).all():
        raise ConfigError("--init-pose must be finite numbers 'tx ty tz qx qy qz qw' with a non-zero quaternion, "
                          f"got a pose with {'NaN or infinite values' if T.shape == (4, 4) else f'shape {T.shape}'}")
    for value in T[:3, 3]:  # a position within the table's range
        check("pose_number", value, "--init-pose")
    R = T[:3, :3]
    if not np.allclose(R @ R.T, np.eye(3), atol=1e-4) or np.linalg.det(R) < 0:
        raise ConfigError("--init-pose: the rotation is not a proper rotation (give a unit quaternion qx qy qz qw)")


def motion_source(name: str, *, noise: float = 0.05, seed: int = 0) -> MotionSource:
    """The motion source ``--motion`` names: ``odometry``, ``gt-noisy`` or the path of a TUM trajectory file."""
    if name == "odometry":
        return OdometrySource()
    if name == "gt-noisy":
        return NoisyGroundTruth(noise, noise, seed=seed)
    path = Path(name)
    if not path.is_file():
        raise ConfigError(f"--motion must be one of {', '.join(MOTION_SOURCES)} or a trajectory file; "
                          + (f"{name} {path_kind(path)}" if path.exists() else f"{name!r} is neither"))
    return TrajectorySource(path)


def _segment_fn(options: LocalizeOptions, dataset, prior):
    """Per-frame class sets for the scans, or None (geometry only)."""
    model = options.settings.model
    name = options.segmenter
    if name == "auto":
        from semmap.perception.registry import SegmenterName

        name = SegmenterName.ORACLE if _has_labels(dataset) else None
    if name in (None, "none"):
        if model != ObservationKind.GEOMETRY:
            where = getattr(dataset, "root", "the sequence")
            raise ConfigError(f"{where}: no label images, and the {model.value} model needs class sets for "
                              f"the frames: pass --segmenter "
                              f"(oracle for sequences with label images, espnetv2 --weights ...) or --model geometry")
        return None
    if prior.label_set is None:
        raise ConfigError("the map has no classes; only --model geometry can localize in it")
    from semmap.perception.registry import make_segmenter

    seg = make_segmenter(name, weights=options.weights, label_set=dataset.label_set or prior.label_set,
                         seed=options.seed, trust_weights=options.trust_weights)
    if seg.label_set != prior.label_set:
        raise ConfigError(f"the segmenter {name!r} predicts {len(seg.label_set)} classes ({seg.label_set.names[:3]}...)"
                          f" but the map holds {len(prior.label_set)} ({prior.label_set.names[:3]}...)")
    return seg.segment


def _has_labels(dataset) -> bool:
    for frame in dataset:
        return frame.labels is not None
    return False


def _tilt_fn(options: LocalizeOptions):
    """Ground mode: the camera's height and tilt per frame (fixed options, else the frame's ground truth)."""
    if options.settings.mode != MotionMode.GROUND:
        return None
    if options.height is not None:
        fixed = GroundTilt.fixed(options.height, options.pitch_deg, options.roll_deg)
        return lambda frame: fixed

    def from_ground_truth(frame: Frame) -> GroundTilt | None:
        return None if frame.T_world_cam is None else GroundTilt.from_pose(frame.T_world_cam)

    return from_ground_truth


def localize_sequence(map_path: Path, seq_path: Path, out_dir: Path, options: LocalizeOptions, *,
                      progress=None) -> tuple[LocalizationResult, dict[str, Path]]:
    """Localize the camera of the sequence ``seq_path`` in the map ``map_path`` and write the outputs."""
    from semmap.datasets import open_dataset

    motion = None if options.motion in MOTION_SOURCES else options.motion
    check_outputs([("--out", out_dir, OutputKind.FOLDER)], [("MAP", map_path), ("SEQ", seq_path),
                                                             ("--motion", motion), ("--weights", options.weights)])
    prior = load_prior(map_path)
    dataset = open_dataset(seq_path, stride=options.stride, max_frames=options.max_frames)
    segment = _segment_fn(options, dataset, prior)
    motion = motion_source(options.motion, noise=options.motion_noise, seed=options.seed)
    result = localize(prior, dataset, motion, settings=options.settings, init=options.init,
                      init_pose=options.init_pose, segment=segment, tilt_of=_tilt_fn(options), points=options.points,
                      seed=options.seed, progress=progress, total=len(dataset))
    sources = {"map": str(map_path), "sequence": str(seq_path), "motion": motion.name,
               "segmenter": None if segment is None else options.segmenter}
    files = write_staged(Path(out_dir), lambda stage: write_outputs(stage, result, prior, gif=options.gif,
                                                                     sources=sources))  # all files, or none
    return result, files
