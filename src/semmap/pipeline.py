"""Wiring of one mapping run: dataset -> poses -> semantics -> maps -> files and report.

``Mapper.integrate`` is the per-frame algorithm; ``Pipeline.run`` is the orchestration (open, integrate every
frame with a progress bar, write outputs).  This module and ``cli.py`` are the only places that wire stages.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import time
from collections import defaultdict
from collections.abc import Callable, Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from semmap.config import ColorMode, LoopMode, RunConfig, SemanticSource
from semmap.datasets import Dataset, open_dataset
from semmap.datasets.prefetch import Prefetcher
from semmap.errors import ConfigError
from semmap.eval.report_html import write_report_html
from semmap.eval.report_md import write_report_md
from semmap.eval.report_plots import write_report_plots
from semmap.eval.semantic import confusion, evaluate_2d, evaluate_cloud_3d
from semmap.frame_arrays import class_sets, frame_from_arrays
from semmap.geometry import backproject_world, pixel_normals
from semmap.interrupt import RunInterrupted, checked, deferred_interrupts, stop_requested
from semmap.io.atomic import write_text_atomic
from semmap.io.staged_run import StagedRun
from semmap.keys import TREE_MAX_VAL
from semmap.maps.base import SemanticMap
from semmap.maps.registry import compile_kernels, get_map
from semmap.object_stage import ObjectStage
from semmap.perception.base import Preparable, Segmenter
from semmap.perception.instances.base import InstanceSource
from semmap.perception.schedule import (
    Scheduler,
    SegmentationSchedule,
    SegmentationWorker,
    with_semantics,
    with_semantics_beside,
)
from semmap.poses.base import LiveTracker, PoseTracker
from semmap.types import (
    CameraIntrinsics,
    Frame,
    LabelSet,
    MapCloud,
    MapKind,
    Observation,
    TopKProbs,
    Trajectory,
    muted_grey,
    rotation_angle,
)
from semmap.viz.preview import CEILING_MARGIN, perspective, side_by_side, top_down, up_vector, write_png
from semmap.viz.rerun_log import NoVisualizer, Visualizer, get_visualizer

log = logging.getLogger("semmap")
#: Fallback label set when labels come without a labelset.json (8-bit label images).
FALLBACK_CLASSES = 256
#: Ground truth for 3D evaluation: resolution -> (keys (M, 3), class ids (M,)) of the true surface voxels.
GroundTruthFn = Callable[[float], tuple[np.ndarray, np.ndarray]]
#: Bytes per point of a dense coloured point cloud stored as binary PLY (xyz float32 + rgb uint8).
DENSE_CLOUD_BYTES_PER_POINT = 15


class Mapper:
    """Integrates frames into maps: back-project, transform, attach colour and class sets, hand to every map."""

    def __init__(self, maps: list[SemanticMap], *, min_depth: float, max_depth: float, pixel_stride: int = 1):
        if not maps:
            raise ConfigError("a mapping run needs at least one map")
        self.maps = maps
        self.min_depth, self.max_depth, self.pixel_stride = min_depth, max_depth, pixel_stride
        self.points_integrated = 0
        self.keyframes = 0
        self.last_was_keyframe = False
        self._keyframe_of = Scheduler(SegmentationSchedule(keyframes=True))
        self._normals = any(m.needs_normals for m in maps)

    def integrate(self, frame: Frame, T_world_cam: np.ndarray, semantics: TopKProbs | None) -> dict[str, float]:
        """Integrate one frame seen from ``T_world_cam`` with optional per-pixel class sets (H, W, k) into every
        map; returns milliseconds per step (the first map's steps by name, the others' as ``kind:step``)."""
        t0 = time.perf_counter()
        # valid depth pixels to world points (paper eq. 7, then the camera pose)
        points_world, pixels = backproject_world(frame.depth, frame.intrinsics, T_world_cam,
                                                 min_depth=self.min_depth, max_depth=self.max_depth,
                                                 stride=self.pixel_stride)
        # colour and class set of each point's pixel
        colors = np.take(frame.rgb.reshape(-1, 3), pixels, axis=0)
        point_sem = None
        if semantics is not None:
            flat = semantics.reshape_flat()
            point_sem = TopKProbs(np.take(flat.labels, pixels, axis=0), np.take(flat.probs, pixels, axis=0))
        # keyframes (the camera moved 10 cm or turned 10° since the last one) and, on them, normals if a map asks
        keyframe = self._keyframe_of.due(T_world_cam)
        self.keyframes += keyframe
        self.last_was_keyframe = keyframe
        normals = (pixel_normals(frame.depth, frame.intrinsics, T_world_cam, pixels)
                   if self._normals and keyframe else None)
        obs = Observation(points_world, np.asarray(T_world_cam, np.float64)[:3, 3].copy(), colors, point_sem,
                          normals=normals, frame_index=frame.index, keyframe=keyframe)
        ms = {"backproject": (time.perf_counter() - t0) * 1e3}
        # each map fuses the same observation (the OctoMap ray-casts free space from the camera centre)
        for i, m in enumerate(self.maps):
            steps = m.integrate(obs)
            ms.update(steps if i == 0 else {f"{m.kind.value}:{k}": v for k, v in steps.items()})
        self.points_integrated += len(points_world)
        return ms

    def integrate_arrays(self, rgb: np.ndarray, depth_m: np.ndarray, intrinsics: CameraIntrinsics | np.ndarray,
                         T_world_cam: np.ndarray, semantics: np.ndarray | TopKProbs | None = None, *, k: int = 3,
                         label_confidence: float = 0.9, index: int = 0) -> dict[str, float]:
        """:meth:`integrate` for a user's own loop: one frame as plain arrays (see
        :func:`semmap.frame_arrays.frame_from_arrays` and :func:`~semmap.frame_arrays.class_sets`)."""
        frame = frame_from_arrays(rgb, depth_m, intrinsics, T_world_cam=T_world_cam, index=index)
        classes = next((len(m.label_set) for m in self.maps if m.label_set is not None), None)
        sem = class_sets(semantics, frame.depth.shape, num_classes=classes, k=k, label_confidence=label_confidence)
        return self.integrate(frame, frame.T_world_cam, sem)


def semantics_for(frame: Frame, source: SemanticSource, *, segmenter: Segmenter | None,
                  label_set: LabelSet | None, label_confidence: float, k: int) -> TopKProbs | None:
    """Per-pixel class sets of a frame according to the configured source."""
    if frame.semantics is not None:
        return frame.semantics
    if source == SemanticSource.NONE or label_set is None:
        return None
    if segmenter is not None:
        return segmenter.segment(frame)
    if frame.labels is not None:
        return TopKProbs.from_hard_labels(frame.labels, label_confidence, len(label_set), k)
    return None


class _FirstFrame:
    """A dataset's first frame, read only when something asks for it (a ROS bag pays a pass over its index)."""

    def __init__(self, dataset: Dataset):
        self._dataset, self._read, self._frame = dataset, False, None

    @property
    def frame(self) -> Frame | None:
        if not self._read:
            self._frame, self._read = next(iter(self._dataset), None), True
        return self._frame


@dataclass
class _LoopState:
    """What the frame loop keeps: the poses frames were mapped with (in order), when each waiting frame was
    read, each frame's latency from being read to being in the maps, and the loop's wall time; and what a
    checkpoint saves besides the maps so that ``--resume`` continues exactly: the loop's sums, the segmentation
    schedule's own state and the last frame mapped."""

    poses: list[np.ndarray] = field(default_factory=list)
    arrival: dict[int, float] = field(default_factory=dict)
    latency_ms: list[float] = field(default_factory=list)
    seconds: float = 0.0
    timings: dict[str, float] = field(default_factory=dict)
    no_pose: list[str] = field(default_factory=list)
    segmented: int = 0
    conf2d: np.ndarray | None = None
    scheduler: Scheduler | None = None
    last_index: int | None = None  # dataset index of the last frame mapped
    last_name: str | None = None


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
        self._gt: list[tuple[float, str, np.ndarray]] = []

    def __call__(self, frame: Frame) -> tuple[np.ndarray | None, str]:
        """(pose or None, why not)."""
        if self.tracker is not None:
            T, reason = self._track(frame), f"{self.source} tracking lost"
        elif self.by_name is not None:
            T = self.by_name.get(frame.name)
            reason = "" if T is not None else f"{self.source} tracking lost"
        elif self.lookup is not None:
            found = self.lookup.pose_of(frame)
            T, reason = found.pose, found.reason
        else:
            T, reason = frame.T_world_cam, "no ground-truth pose"
        if frame.T_world_cam is not None:
            self._gt.append((frame.timestamp, frame.name, frame.T_world_cam))
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

    @staticmethod
    def _trajectory(rows: list[tuple[float, str, np.ndarray]]) -> Trajectory:
        rows = sorted(rows, key=lambda r: r[0])
        return Trajectory(np.array([r[0] for r in rows]), np.array([r[2] for r in rows]).reshape(-1, 4, 4),
                          tuple(r[1] for r in rows))

    def used_trajectory(self) -> Trajectory:
        return self._trajectory(self._used)

    def ground_truth(self) -> Trajectory:
        return self._trajectory(self._gt)


@dataclass
class RunResult:
    """What a run produced: the maps (the first is the primary one the report's top level describes), where
    files went, the report dict."""

    maps: list[SemanticMap]
    out_dir: Path
    report: dict
    files: dict[str, Path] = field(default_factory=dict)
    poses: list[np.ndarray] = field(default_factory=list)

    def map_of(self, kind: MapKind) -> SemanticMap | None:
        return next((m for m in self.maps if m.kind == kind), None)

    @property
    def octomap(self):
        """The semantic OctoMap of the run, if one was built."""
        return self.map_of(MapKind.OCTOMAP)


class Pipeline:
    """One mapping run from a dataset folder to ``map.ot``, ``map.bt``, ``map.semmap``, preview and report."""

    def __init__(self, config: RunConfig, *, segmenter: Segmenter | None = None,
                 progress: Callable[[Iterator, int], Iterator] | None = None, dataset: Dataset | None = None,
                 ground_truth: GroundTruthFn | None = None, title: str = "semmap run",
                 track_progress: Callable[[Iterator, int], Iterator] | None = None,
                 instances: InstanceSource | None = None, checkpoint_every: int = 0, resume: bool = False):
        self.config = config
        self.checkpoint_every, self.resume = int(checkpoint_every), bool(resume)
        self._out = config.output.out  # the staging folder while the run writes (io.staged_run)
        self._loop = _LoopState()
        self.segmenter = segmenter
        self.instances = instances  # an instance source builds the object map beside the maps
        self._objects: ObjectStage | None = None
        self.progress = progress or (lambda it, n: it)
        self.track_progress = track_progress
        self.dataset = dataset
        self.ground_truth = ground_truth
        self.title = title
        self._conf2d: np.ndarray | None = None
        self._segmented = 0
        self._viewer: Visualizer = NoVisualizer()
        self._gt: dict[float, tuple[np.ndarray, np.ndarray]] = {}

    def run(self) -> RunResult:
        """Map the sequence; outputs appear in ``--out`` all at once at the end (a failure or Ctrl-C leaves it as it
        was, and with checkpoints the staging folder to ``--resume`` from)."""
        check_out_dir(self.config.output.out)
        self._check_checkpoint_options()
        staged = StagedRun(self.config.output.out, resume=self.resume)
        with deferred_interrupts():
            self._out = staged.open()
            try:
                result = self._run(staged)
            except RunInterrupted as exc:
                raise RunInterrupted(f"{exc}; {staged.abandon(keep_checkpoint=True)}") from None
            except BaseException:
                staged.abandon(keep_checkpoint=self.checkpoint_every > 0 or self.resume)
                raise
            finally:
                self._out = self.config.output.out
        return result

    def _check_checkpoint_options(self) -> None:
        if self.checkpoint_every < 0:
            raise ConfigError(f"--checkpoint-every must be 0 (off) or a number of frames, got {self.checkpoint_every}")
        if not (self.checkpoint_every or self.resume):
            return
        if self.config.mode == LoopMode.ONLINE:
            raise ConfigError("--checkpoint-every / --resume work offline only (online, the tracker's state is not "
                              "saved)")
        if self.instances is not None:
            raise ConfigError("--checkpoint-every / --resume do not support --instances yet (the object tracker's "
                              "state is not saved)")
        if self.segmenter is not None and self.config.semantics.batch_size > 1:
            raise ConfigError("--checkpoint-every / --resume need --batch-size 1 (a batch reads frames ahead)")

    def _run(self, staged: StagedRun) -> RunResult:
        self._conf2d = None
        self._viewer = get_visualizer(self.config.output, name=self.title)
        dataset = self._open()
        label_set = self._label_set(dataset)
        kinds = self._map_kinds()
        startup_s = compile_kernels(kinds)  # keeps numba's first-use compilation out of the per-frame timings
        first = _FirstFrame(dataset)  # what a segmenter and an online tracker get ready on (read if needed)
        segmenter_s = self._prepare_segmenter(first)  # and an ONNX export / session out of the first frame's
        maps = [get_map(kind, self.config, label_set) for kind in kinds]
        mapper = Mapper(maps, min_depth=self.config.mapping.min_depth, max_depth=self.config.mapping.max_depth,
                        pixel_stride=self.config.mapping.pixel_stride)
        self._staged = staged
        resumed = staged.load_checkpoint(self.config.to_json()) if self.resume else None
        if resumed is not None:  # the maps, poses and sums of the last checkpoint; its frames are not read again
            (mapper, pose_of, self._loop), _, name = resumed
            maps = mapper.maps
            log.info("resuming %s after frame %s", self.config.input.dataset, name)
        else:
            pose_of = self._pose_source(dataset)
            self._loop = _LoopState()
        startup_s += self._prepare_tracker(first)
        self._objects = ObjectStage(self.instances) if self.instances is not None else None
        if self._objects is not None:
            self._viewer.show_objects(self._objects.map.real_objects, self._objects.map.label_set)
        timings, poses, no_pose = self._integrate_all(dataset, mapper, label_set, pose_of)
        self._viewer.finish(maps[0])
        self._warn_if_empty(maps[0], mapper, poses)
        crf = self._refine(maps, poses) if self.config.crf.enabled else {}
        files, sizes = self._write_outputs(maps, poses)
        report = self._report(dataset, mapper, timings, poses, no_pose, sizes)
        report["startup_s"] = round(startup_s + segmenter_s, 3)
        if self.segmenter is not None:
            report["segmenter_startup_s"] = round(segmenter_s, 3)
        report.update(self._trajectory_outputs(pose_of, files))
        report["peak_rss_mb"] = round(peak_rss_mb(), 1)
        # frames per second of the work a frame needs (the tracking pass before, offline, and the frame loop)
        before = (pose_of.tracking_s or 0.0) if pose_of.tracker is None else 0.0  # online it is inside the loop
        pass_s = self._loop.seconds + before
        report["frames_per_second"] = round(len(poses) / max(pass_s, 1e-9), 2)
        if self.config.mode == LoopMode.ONLINE:
            report["online"] = self._online_report(pose_of, files)
        if self._objects is not None:
            report["objects"] = self._objects.report(mapper.keyframes)
        report.update(self._evaluate(maps[0]))
        if maps[0].kind in crf and "miou_3d_before" in crf[maps[0].kind]:
            report["miou_3d_before_crf"] = crf[maps[0].kind]["miou_3d_before"]
        if len(maps) > 1 or crf:
            report["maps"] = self._maps_report(maps, sizes, crf)
        out = self._out
        write_text_atomic(out / "report.json", json.dumps(report, indent=2))
        plots = write_report_plots(out, report, used=pose_of.used_trajectory(), ground_truth=pose_of.ground_truth(),
                                   cloud=maps[0].cloud()) if self.config.output.plots else {}
        write_report_md(out / "report.md", report, title=self.title, plots=plots)
        write_report_html(out / "report.html", (out / "report.md").read_text(), title=self.title)
        files["report"], files["report_md"] = out / "report.json", out / "report.md"
        files["report_html"] = out / "report.html"
        files.update({f"plot_{name}": out / file for name, file in plots.items()})
        if stop_requested():
            raise RunInterrupted("interrupted while writing the outputs")
        staged.commit()  # every file is there: the folder becomes --out in one rename
        final = self.config.output.out
        files = {key: final / Path(path).relative_to(out) for key, path in files.items()}
        return RunResult(maps, final, report, files, poses)

    # ---------------------------------------------------------------- steps
    def _open(self) -> Dataset:
        if self.dataset is not None:
            return self.dataset
        c = self.config.input
        return open_dataset(c.dataset, c.format, labels=c.labels, stride=c.stride, max_frames=c.max_frames,
                            raw_color=c.raw_color, ros=c.ros.options(), strict=c.strict)

    def _prepare_segmenter(self, first: _FirstFrame) -> float:
        """Let a segmenter with a start-up cost pay it on the dataset's first frame; returns the seconds."""
        if not isinstance(self.segmenter, Preparable) or first.frame is None:
            return 0.0
        return self.segmenter.prepare(first.frame)

    def _prepare_tracker(self, first: _FirstFrame) -> float:
        """Online, run a throwaway tracker of the same kind on the first frame twice, so that its kernels are
        compiled (or loaded) before the first frame's latency is counted; returns the seconds."""
        if self.config.mode != LoopMode.ONLINE or self.config.poses.source == "gt":
            return 0.0
        from semmap.poses.track import METHODS, make_tracker

        source = self.config.poses.source
        if source not in METHODS or first.frame is None:  # (object-constrained trackers share the instance
            return 0.0  # source's state: not warmed)
        t0 = time.perf_counter()
        warm = make_tracker(source)
        for _ in range(2):
            warm.track(first.frame)
        return time.perf_counter() - t0

    def _label_set(self, dataset: Dataset) -> LabelSet | None:
        """The classes of the map: the segmenter's, the dataset's, a generic set when label images come
        without names, or none (geometry and colour only)."""
        if self.segmenter is not None:
            return self.segmenter.label_set
        if dataset.label_set is not None:
            return dataset.label_set
        s = self.config.semantics.source
        if s == SemanticSource.LABELS or (s == SemanticSource.AUTO and self.config.input.labels is not None):
            return LabelSet.generic(FALLBACK_CLASSES)
        return None

    def _map_kinds(self) -> list[MapKind]:
        """The maps this run builds, the primary one first."""
        return list(self.config.mapping.maps)

    def _refine(self, maps: list[SemanticMap], poses: list[np.ndarray]) -> dict[MapKind, dict]:
        """3D dense CRF over every map with class distributions; per map: its accuracy before (when there is
        ground truth), elements refined and changed, milliseconds."""
        from semmap.fusion.crf import CrfParams, refine_map

        params = CrfParams(iterations=self.config.crf.iterations)
        viewpoint = np.mean([np.asarray(T)[:3, 3] for T in poses], axis=0) if poses else None
        out: dict[MapKind, dict] = {}
        for m in maps:
            if m.label_set is None:
                continue
            before = self._evaluate_3d(m)
            r = refine_map(m, params, viewpoint=viewpoint)
            out[m.kind] = {**({"miou_3d_before": before["miou_3d"],
                                "voxel_accuracy_3d_before": before["voxel_accuracy_3d"]} if before else {}),
                           "refined": r.refined, "changed": r.changed, "ms": round(r.ms, 1)}
        return out

    def _ground_truth(self, resolution: float) -> tuple[np.ndarray, np.ndarray]:
        if resolution not in self._gt:
            self._gt[resolution] = self.ground_truth(resolution)
        return self._gt[resolution]

    def _evaluate_3d(self, m: SemanticMap) -> dict:
        """3D accuracy of a map against ground truth at the run's voxel size (a finer point map votes per voxel);
        empty without ground truth or classes."""
        if self.ground_truth is None or m.label_set is None:
            return {}
        resolution = self.config.mapping.resolution
        gt_keys, gt_labels = self._ground_truth(resolution)
        cloud = m.cloud()
        return evaluate_cloud_3d(cloud.centers, cloud.labels, gt_keys, gt_labels, m.label_set, resolution)

    def _maps_report(self, maps: list[SemanticMap], sizes: dict[str, int], crf: dict[MapKind, dict]) -> dict:
        """Each map side by side: what it holds, its files, its accuracy (and before the CRF)."""
        out = {}
        for m in maps:
            files = {name: size for name, size in sizes.items() if name in _files_of(m)}
            entry = {"resolution": m.resolution, **m.describe(), "files": files, **self._evaluate_3d(m)}
            if m.kind in crf:
                entry["crf"] = crf[m.kind]
            out[m.kind.value] = entry
        return out

    def _pose_source(self, dataset: Dataset) -> FramePoses:
        """Where each frame's pose comes from: ground truth, a trajectory file, or a tracker run over the
        sequence first (its final, loop-closed trajectory is then used for mapping)."""
        source = self.config.poses.source
        if source == "gt":
            return FramePoses("gt")
        from semmap.object_slam import OBJECT_METHODS, make_pose_tracker
        from semmap.poses.base import estimate_trajectory
        from semmap.poses.track import METHODS

        if source in METHODS or source in OBJECT_METHODS:
            t0 = time.perf_counter()
            tracker = make_pose_tracker(source, instances=self.instances)
            if self.config.mode == LoopMode.ONLINE:  # tracked in the frame loop, frame by frame
                return FramePoses(source, tracker=tracker)
            progress = self.track_progress or (lambda it, n: it)
            trajectory = estimate_trajectory(tracker, dataset, total=len(dataset),  # Ctrl-C stops between frames
                                             progress=lambda it, n: checked(progress(it, n), "tracking"))
            tracking_s = time.perf_counter() - t0
            if len(trajectory) == 0:
                raise ConfigError(f"{self.config.input.dataset}: the {source} tracker lost every frame")
            stats = getattr(tracker, "stats", None)
            return FramePoses(source, by_name=dict(zip(trajectory.names, trajectory.poses, strict=True)),
                              tracking_s=tracking_s, tracked=len(trajectory),
                              edge_stats=dataclasses.asdict(stats) if dataclasses.is_dataclass(stats) else None)
        from semmap.poses.file import TrajectoryPoses

        path = Path(source)
        if not path.is_file():
            raise ConfigError(f"--poses must be gt, a tracker ({', '.join(METHODS + OBJECT_METHODS)}) or a "
                              f"trajectory file; {path} does not exist")
        return FramePoses(str(path), lookup=TrajectoryPoses.from_file(path,
                                                                      max_time_diff=self.config.poses.max_time_diff))

    def _online_report(self, pose_of: FramePoses, files: dict[str, Path]) -> dict:
        """Frame rate and latency of the online loop, and the drift its map keeps: how far each frame's final,
        loop-closed pose lies from the pose it was mapped with (``trajectory_final.txt``; mapping it again,
        offline, is ``--poses trajectory_final.txt``)."""
        loop = self._loop
        lat = np.asarray(loop.latency_ms)
        out: dict = {"fps": round(len(loop.poses) / max(loop.seconds, 1e-9), 2), "loop_s": round(loop.seconds, 2),
                     "latency_ms": {"median": round(float(np.median(lat)), 1),
                                    "p95": round(float(np.percentile(lat, 95)), 1), "max": round(float(lat.max()), 1)}}
        if pose_of.tracker is None:
            return {**out, "drift_left_in": drift_left_in(pose_of.used_trajectory(), pose_of.used_trajectory(),
                                                           self.config.mapping.resolution)}
        from semmap.io.trajectory import write_trajectory

        final = pose_of.tracker.trajectory()
        files["trajectory_final"] = write_trajectory(self._out / "trajectory_final.txt", final)
        if isinstance(pose_of.tracker, LiveTracker):
            out["loop_closures"] = pose_of.tracker.loop_closures
        out["drift_left_in"] = drift_left_in(pose_of.used_trajectory(), final, self.config.mapping.resolution)
        gt = pose_of.ground_truth()
        if len(gt) >= 3 and len(final) >= 3:
            from semmap.eval.trajectory import evaluate_trajectory

            try:
                scores = evaluate_trajectory(gt, final)
            except ConfigError as exc:  # a camera that never moved cannot be aligned: no score, not a failed run
                log.warning("the final trajectory is not scored: %s", exc)
            else:
                out["final_trajectory_vs_ground_truth"] = {k: scores[k] for k in ("ate_rmse_m", "rpe_trans_m",
                                                                                  "matched") if k in scores}
        return out

    def _trajectory_outputs(self, pose_of: FramePoses, files: dict[str, Path]) -> dict:
        """Write the poses used into ``trajectory.txt``; score them against ground truth when there is one."""
        from semmap.io.trajectory import write_trajectory

        out: dict = {"poses": pose_of.source}
        used = pose_of.used_trajectory()
        if len(used):
            files["trajectory"] = write_trajectory(self._out / "trajectory.txt", used)
        if pose_of.tracking_s is not None:
            out["tracking_ms_per_frame"] = round(1e3 * pose_of.tracking_s / max(pose_of.tracked, 1), 2)
        if pose_of.edge_stats is not None:
            out["object_pose_edges"] = pose_of.edge_stats
        gt = pose_of.ground_truth()
        if pose_of.source != "gt" and len(gt) >= 3 and len(used) >= 3:
            from semmap.eval.trajectory import evaluate_trajectory

            scores = evaluate_trajectory(gt, used)
            out["trajectory_vs_ground_truth"] = {k: scores[k] for k in ("ate_rmse_m", "rpe_trans_m", "matched")
                                                 if k in scores}
        return out

    def _integrate_all(self, dataset: Dataset, mapper: Mapper, label_set: LabelSet | None, pose_of: FramePoses):
        """The frame loop: frames (loaded, posed) -> semantics -> every map, one frame at a time in order.

        Offline, poses are the tracker's final trajectory (tracked in a pass before) and due frames are segmented
        in batches; online, each frame is tracked as it arrives and due frames are segmented on a thread beside
        tracking. Either way ``_integrate_frame`` sees the same frames in the same order."""
        loop = self._loop  # empty, or what a checkpoint saved
        timings: dict[str, float] = defaultdict(float, loop.timings)
        no_pose = loop.no_pose
        self._segmented, self._conf2d = loop.segmented, loop.conf2d
        t0 = time.perf_counter() - loop.seconds
        with self._semantic_stream(self._posed_frames(dataset, timings, no_pose, pose_of, loop), label_set,
                                   timings) as stream:
            for frame, T, sem in stream:
                self._integrate_frame(frame, T, sem, mapper, label_set, timings, loop)
                self._after_frame(frame, mapper, pose_of, timings)
        loop.seconds = time.perf_counter() - t0
        if not loop.poses:
            hint = " (poses come from the dataset's ground truth, e.g. TUM groundtruth.txt)" if no_pose else ""
            raise ConfigError(f"{self.config.input.dataset}: no frame could be mapped "
                              f"({len(dataset.skipped)} unreadable, {len(no_pose)} without pose){hint}")
        self._loop = loop
        return timings, loop.poses, no_pose

    @contextmanager
    def _semantic_stream(self, posed: Iterator[tuple[Frame, np.ndarray]], label_set: LabelSet | None,
                         timings: dict[str, float]) -> Iterator[Iterator[tuple[Frame, np.ndarray, TopKProbs | None]]]:
        """``(frame, pose, semantics or None)`` in frame order: from the segmenter (in batches offline, on a
        thread beside tracking online) or from the frames' own labels."""
        s = self.config.semantics
        if self.segmenter is None:
            yield ((f, T, semantics_for(f, s.source, segmenter=None, label_set=label_set,
                                        label_confidence=s.label_confidence, k=s.k)) for f, T in posed)
            return
        if self._loop.scheduler is None:  # (a resumed run continues the checkpoint's schedule)
            self._loop.scheduler = Scheduler(SegmentationSchedule(every=s.segment_every, keyframes=s.keyframes))
        scheduler = self._loop.scheduler
        if self.config.mode == LoopMode.OFFLINE:
            yield with_semantics(posed, self.segmenter, scheduler, batch_size=s.batch_size, timings=timings)
            return
        o = self.config.online
        with SegmentationWorker(self.segmenter, max_queued=o.segment_queue,
                                numba_threads=o.segment_numba_threads) as worker:
            yield with_semantics_beside(posed, worker, scheduler, max_pending=o.max_pending, timings=timings)

    def _integrate_frame(self, frame: Frame, T: np.ndarray, sem: TopKProbs | None, mapper: Mapper,
                         label_set: LabelSet | None, timings: dict[str, float], loop: _LoopState) -> None:
        """One frame into every map (and the object map, the CRF and the viewer), the moment its pose and
        semantics are there; its latency since it was read."""
        if self.segmenter is not None and sem is not None:
            self._segmented += 1
            if frame.labels is not None:
                self._score_segmentation(sem, frame.labels, len(label_set))
        for name, ms in mapper.integrate(frame, T, sem).items():
            timings[name] += ms
        if self._objects is not None:  # instances and tracks every frame, the object map on keyframes
            t_obj = time.perf_counter()
            self._objects.step(frame, T, sem, mapper.last_was_keyframe)
            timings["objects"] += (time.perf_counter() - t_obj) * 1e3
        every = self.config.crf.every
        if self.config.crf.enabled and every and mapper.last_was_keyframe and mapper.keyframes % every == 0:
            t_crf = time.perf_counter()
            self._refine(mapper.maps, [*loop.poses, T])
            timings["crf"] += (time.perf_counter() - t_crf) * 1e3
        loop.poses.append(T)
        loop.latency_ms.append((time.perf_counter() - loop.arrival.pop(id(frame))) * 1e3)
        self._viewer.log_frame(frame, T, sem, mapper.maps[0])

    def _after_frame(self, frame: Frame, mapper: Mapper, pose_of: FramePoses, timings: dict[str, float]) -> None:
        """Checkpoint every ``checkpoint_every`` mapped frames (and on Ctrl-C), then stop here if asked to."""
        loop = self._loop
        loop.last_index, loop.last_name = int(frame.index), frame.name
        interrupted = stop_requested()
        if self.checkpoint_every and (len(loop.poses) % self.checkpoint_every == 0 or interrupted):
            loop.timings, loop.segmented, loop.conf2d = dict(timings), self._segmented, self._conf2d
            saved = dataclasses.replace(loop, arrival={})  # (offline with batches of one: nothing is waiting)
            self._staged.save_checkpoint((mapper, pose_of, saved), config_json=self.config.to_json(),
                                         frame_index=loop.last_index, frame_name=frame.name)
        if interrupted:
            raise RunInterrupted(f"interrupted after frame {frame.name} ({len(loop.poses)} frames mapped)")

    def _warn_if_empty(self, primary: SemanticMap, mapper: Mapper, poses: list[np.ndarray]) -> None:
        """A run whose frames added nothing to the map says so, with the likely reason."""
        if len(primary.cloud()):
            return
        m = self.config.mapping
        reasons = []
        reach = TREE_MAX_VAL * m.resolution
        far = max((float(np.abs(np.asarray(T)[:3, 3]).max()) for T in poses), default=0.0)
        if far >= reach:
            reasons.append(f"camera poses lie up to {far:,.0f} m from the origin, beyond the ±{reach:,.0f} m a map of "
                           f"resolution {m.resolution} m can hold")
        if mapper.points_integrated == 0:
            reasons.append(f"no depth pixel lies between --min-depth {m.min_depth} and --max-depth {m.max_depth} m")
        if 0 <= m.max_range < m.resolution:
            reasons.append(f"--max-range {m.max_range} m leaves every reading beyond range")
        log.warning("%d frames added nothing to the map: no voxel is occupied (%s)", len(poses),
                    "; ".join(reasons) or "check the poses and depth units")

    def _posed_frames(self, dataset: Dataset, timings: dict[str, float], no_pose: list[str], pose_of: FramePoses,
                      loop: _LoopState):
        """``(frame, T_world_cam)`` for every readable frame with a pose, behind the progress bar; frames
        without a pose are warned about and listed in ``no_pose``.  Online, the next frames are read on a
        thread meanwhile and the tracker runs here.  ``load`` is the time the loop waited for a frame."""
        after = loop.last_index  # frames up to it are in the checkpoint's maps already
        with self._arrivals(dataset) as arrivals:
            t_wait = time.perf_counter()
            for frame, arrived in self.progress(arrivals, len(dataset)):
                if stop_requested():
                    raise RunInterrupted(f"interrupted after frame {loop.last_name or '(none)'} "
                                         f"({len(loop.poses)} frames mapped)")
                if after is not None and frame.index <= after:
                    t_wait = time.perf_counter()
                    continue
                t_pose = time.perf_counter()
                timings["load"] += (t_pose - t_wait) * 1e3
                T, reason = pose_of(frame)
                if pose_of.tracker is not None:
                    timings["track"] += (time.perf_counter() - t_pose) * 1e3
                if T is None:
                    log.warning("frame %s has no pose (%s); skipped", frame.name, reason)
                    no_pose.append(frame.name)
                else:
                    loop.arrival[id(frame)] = arrived
                    yield frame, T
                t_wait = time.perf_counter()

    @contextmanager
    def _arrivals(self, dataset: Dataset) -> Iterator[Iterable[tuple[Frame, float]]]:
        """The dataset's frames with the time each arrived: read ahead on a thread online (bounded; at
        ``online.rate`` frames per second when set, as a live camera delivers them), in turn offline."""
        if self.config.mode == LoopMode.ONLINE:
            with Prefetcher(dataset, depth=self.config.online.read_ahead, rate=self.config.online.rate) as frames:
                yield frames
        else:
            yield ((frame, time.perf_counter()) for frame in dataset)

    def _score_segmentation(self, sem: TopKProbs, gt_labels: np.ndarray, num_classes: int) -> None:
        """Accumulate the per-pixel confusion of the segmenter against ground-truth labels."""
        conf = confusion(sem.labels[..., 0], gt_labels, num_classes)
        self._conf2d = conf if self._conf2d is None else self._conf2d + conf

    def _evaluate(self, primary: SemanticMap) -> dict:
        """Accuracy against ground truth when there is any: 3D voxels, and the segmenter per pixel."""
        out: dict = {}
        if primary.label_set is None:
            return out
        if self._conf2d is not None:
            out.update(evaluate_2d(self._conf2d, primary.label_set, self.segmenter.name))
        out.update(self._evaluate_3d(primary))
        return out

    def _write_outputs(self, maps: list[SemanticMap], poses: list[np.ndarray]):
        """Every map's files, the preview of the primary map and the configuration."""
        out = self._out
        out.mkdir(parents=True, exist_ok=True)
        sizes: dict[str, int] = {}
        for m in maps:
            sizes.update(m.save(out))
        files = {name: out / name for name in sizes}
        if self._objects is not None:
            sizes.update(self._objects.write(out, up_vector(poses)))
            files.update({name: out / name for name in ("objects.json", "objects.ply")})
        if self.config.output.preview:
            for i, m in enumerate(maps):  # preview.png of the primary map, preview_<kind>.png of the others
                name = "preview.png" if i == 0 else f"preview_{m.kind.value}.png"
                files[name] = out / name
                image = render_preview(m.cloud(), m.label_set, poses)
                if i == 0 and self._objects is not None:  # the objects with their ids beside it
                    panel = self._objects.panel(up_vector(poses), size=image.shape[0] - 28)
                    image = side_by_side([image, panel], ["", "objects (top-down): id class"])
                sizes[name] = write_png(files[name], image)
        write_text_atomic(out / "config.json", self.config.to_json())
        files["config"] = out / "config.json"
        return files, sizes

    def _report(self, dataset: Dataset, mapper: Mapper, timings: dict, poses: list, no_pose: list,
                sizes: dict) -> dict:
        n = len(poses)
        primary = mapper.maps[0]
        ms = {k: round(v / n, 3) for k, v in timings.items()}
        # online, segmentation runs on its own thread: the loop pays only the time it waits for it
        beside = {"segment"} if self.config.mode == LoopMode.ONLINE else set()
        ms["total"] = round(sum(v for k, v in ms.items() if k not in beside), 3)
        return {
            "dataset": str(self.config.input.dataset),
            "resolution": primary.resolution,
            "frames_used": n,
            "frames_skipped": len(dataset.skipped) + len(no_pose),
            "skipped": [{"name": s.name, "path": s.path, "reason": s.reason} for s in dataset.skipped]
            + [{"name": name, "path": "", "reason": "no pose"} for name in no_pose],
            **primary.describe(),
            "bytes_on_disk": sizes,
            "dense_point_cloud_bytes": mapper.points_integrated * DENSE_CLOUD_BYTES_PER_POINT,
            "points_integrated": mapper.points_integrated,
            "ms_per_frame": ms,
            "label_set": None if primary.label_set is None else len(primary.label_set),
            **self._semantics_summary(primary),
        }

    def _semantics_summary(self, primary: SemanticMap) -> dict:
        """Segmenter, frames segmented and occupied voxels per most probable class (classes with voxels)."""
        out: dict = {}
        if self.segmenter is not None:
            out["segmenter"] = self.segmenter.name
            out["frames_segmented"] = self._segmented
        if primary.label_set is not None:
            top = primary.cloud().labels
            names = primary.label_set.names
            counts = np.bincount(top[top < len(names)].astype(np.int64), minlength=len(names))
            order = np.argsort(-counts, kind="stable")
            out["voxels_per_class"] = {names[i]: int(counts[i]) for i in order if counts[i] > 0}
            out["voxels_without_class"] = int((top >= len(names)).sum())
        return out


def _files_of(m: SemanticMap) -> set[str]:
    """Names of the files ``m.save`` writes (the OctoMap's map.*; other maps <kind>.*), and its preview."""
    stem = "map" if m.kind == MapKind.OCTOMAP else m.kind.value
    return {f"{stem}.ot", f"{stem}.bt", f"{stem}.semmap", f"{stem}.ply", f"preview_{m.kind.value}.png"}


def drift_left_in(used: Trajectory, final: Trajectory, resolution: float) -> dict:
    """How far each frame's final pose lies from the pose it was mapped with (frames matched by name):
    translation (mm) and rotation (degrees), max and 95th percentile, and frames moved more than half a voxel."""
    where = {name: i for i, name in enumerate(final.names)}
    pairs = [(i, where[name]) for i, name in enumerate(used.names) if name in where]
    if not pairs:
        return {"frames": 0, "max_mm": 0.0, "p95_mm": 0.0, "max_deg": 0.0, "frames_over_half_voxel": 0}
    a = used.poses[[i for i, _ in pairs]]
    b = final.poses[[j for _, j in pairs]]
    dt = np.linalg.norm(a[:, :3, 3] - b[:, :3, 3], axis=1) * 1e3
    deg = np.array([np.degrees(rotation_angle(x[:3, :3].T @ y[:3, :3])) for x, y in zip(a, b, strict=True)])
    return {"frames": len(pairs), "max_mm": round(float(dt.max()), 2), "p95_mm": round(float(np.percentile(dt, 95)), 2),
            "max_deg": round(float(deg.max()), 3), "frames_over_half_voxel": int((dt > 500 * resolution).sum())}


def peak_rss_mb() -> float:
    """Peak resident memory of this process so far (MiB)."""
    import resource
    import sys

    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak / 2**20 if sys.platform == "darwin" else peak / 1024


def render_preview(cloud: MapCloud, label_set: LabelSet | None, poses: list[np.ndarray]) -> np.ndarray:
    """Top-down views of a map's voxels or points: class colours (grey where unclassified) and observed RGB."""
    up = up_vector(poses)
    cam_h = max(float(np.asarray(T)[:3, 3] @ up) for T in poses) if poses else None
    cut = None if cam_h is None else cam_h + CEILING_MARGIN
    res = cloud.resolution
    views = [top_down(cloud.centers, cloud.colors, res, up=up, max_height=cut)]
    titles = ["colour (top-down)"]
    if label_set is not None:
        top = cloud.labels
        ok = (top < len(label_set)) & (top != 0)  # no class, or unknown / background: observed grey
        class_colors = muted_grey(cloud.colors)
        class_colors[ok] = label_set.colors[top[ok]]
        views.insert(0, top_down(cloud.centers, class_colors, res, up=up, max_height=cut))
        titles.insert(0, "classes (top-down)")
        views.append(perspective(cloud.centers, class_colors, res, up=up, max_height=cut,
                                 width=views[0].shape[1], height=views[0].shape[0]))
        titles.append("classes (perspective)")
    else:
        views.append(perspective(cloud.centers, cloud.colors, res, up=up, max_height=cut,
                                 width=views[0].shape[1], height=views[0].shape[0]))
        titles.append("colour (perspective)")
    return side_by_side(views, titles)


def check_out_dir(out: Path) -> None:
    """``--out`` must be a folder or not exist yet (nor lie below a file): checked before any frame is mapped."""
    for where in (out, *out.parents):
        if where.exists():
            if not where.is_dir():
                what = "is a file" if where == out else f"lies below {where}, which is a file"
                raise ConfigError(f"--out {out}: {what}; give a folder (nothing was mapped)")
            return


def color_mode(value: str) -> ColorMode:
    try:
        return ColorMode(value)
    except ValueError:
        raise ConfigError(f"color mode must be one of {[m.value for m in ColorMode]}, got {value!r}") from None
