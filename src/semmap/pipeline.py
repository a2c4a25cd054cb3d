"""The frame loop of one mapping run: dataset -> poses -> semantics -> maps.

``Mapper.integrate`` is the per-frame algorithm; ``Pipeline.run`` is the run: get ready (``semmap.run.prepare``),
the frame loop (here), the files (``semmap.run.outputs``) and the report (``semmap.eval.run_report``), staged and
checkpointed (``semmap.run.checkpoints``).
"""

from __future__ import annotations

import logging
import time
from collections import defaultdict
from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from semmap.config import LoopMode, RunConfig, SemanticSource
from semmap.datasets import Dataset
from semmap.datasets.prefetch import Prefetcher
from semmap.errors import ConfigError
from semmap.eval.run_report import GroundTruthFn, RunOutcome, RunRecord, RunScorer, build_report, write_report
from semmap.factories import get_map, open_dataset_of
from semmap.frame_arrays import class_sets, frame_from_arrays
from semmap.geometry import backproject_world, pixel_normals
from semmap.interrupt import RunInterrupted, deferred_interrupts, stop_requested
from semmap.io.staged_run import StagedRun
from semmap.io.state import prefixed, section
from semmap.keys import TREE_MAX_VAL
from semmap.limits import BYTES_PER_VOXEL, check_map_extent, check_map_growth, human
from semmap.maps.base import SemanticMap
from semmap.maps.registry import MapKind, compile_kernels
from semmap.maps.semantic_grid import SemanticGrid
from semmap.object_stage import ObjectStage
from semmap.perception.base import Segmenter
from semmap.perception.calibration import apply_temperature
from semmap.perception.instances.base import InstanceSource
from semmap.perception.schedule import (
    Scheduler,
    SegmentationSchedule,
    SegmentationWorker,
    with_semantics,
    with_semantics_beside,
)
from semmap.poses.base import Progress
from semmap.poses.frame_poses import FramePoses
from semmap.poses.track import GROUND_TRUTH
from semmap.run.checkpoints import Checkpoints, check_checkpoint_options
from semmap.run.continuation import PriorRun
from semmap.run.outputs import refine_maps, warn_if_empty, write_outputs
from semmap.run.paths import check_run_paths, staged_output
from semmap.run.prepare import (
    FirstFrame,
    check_labels_exist,
    dynamic_classes,
    label_set_for,
    pose_source_for,
    pose_source_to_resume,
    prepare_segmenter,
    semantics_source,
    simulated_realism,
    warm_tracker,
)
from semmap.types import CameraIntrinsics, Frame, LabelSet, Observation, TopKProbs
from semmap.viz.rerun_log import NoVisualizer, Visualizer, get_visualizer

log = logging.getLogger("semmap")
#: Frames that add nothing to the map are named up to this many times per run.
MAX_EMPTY_FRAME_WARNINGS = 5


#: voxels one view may span before the run warns that mapping it will be slow (about 5 s per frame on 2 cores)
SLOW_VIEW_CELLS = 20_000_000


class Mapper:
    """Integrates frames into maps: back-project, transform, attach colour and class sets, hand to every map."""

    def __init__(self, maps: list[SemanticMap], *, min_depth: float, max_depth: float, pixel_stride: int = 1,
                 cloud_resolution: float | None = None, dynamic: Iterable[int] = ()):
        if not maps:
            raise ConfigError("a mapping run needs at least one map")
        self.maps = maps
        # the dense coloured cloud every point builds, voxel-filtered (cloud.ply: the storage the maps replace)
        self.cloud = SemanticGrid(cloud_resolution, label_set=None) if cloud_resolution else None
        self.min_depth, self.max_depth, self.pixel_stride = min_depth, max_depth, pixel_stride
        self.dynamic = tuple(sorted({int(c) for c in dynamic}))  # classes whose points only clear free space
        self._is_dynamic = dynamic_table(self.dynamic)
        self.points_integrated = 0
        self.points_cleared = 0  # of those, points of dynamic classes (their rays cleared, nothing was added)
        self.keyframes = 0
        self.last_was_keyframe = False
        self._keyframe_of = Scheduler(SegmentationSchedule(keyframes=True))
        self._normals = any(m.needs_normals for m in maps)
        self._extent_checked = False  # the memory of the free space the first frame spans, checked once
        self._held = 0  # bytes the maps held after the last frame

    def integrate(self, frame: Frame, T_world_cam: np.ndarray, semantics: TopKProbs | None) -> dict[str, float]:
        """Integrate one frame seen from ``T_world_cam`` with optional per-pixel class sets (H, W, k) into every
        map; returns milliseconds per step (the first map's steps by name, the others' as ``kind:step``)."""
        t0 = time.perf_counter()
        # valid depth pixels to world points (paper eq. 7, then the camera pose)
        points_world, pixels = backproject_world(frame.depth, frame.intrinsics, T_world_cam,
                                                 min_depth=self.min_depth, max_depth=self.max_depth,
                                                 stride=self.pixel_stride)
        if not self._extent_checked and len(points_world):
            self._extent_checked = True
            self._check_extent(points_world, np.asarray(T_world_cam, np.float64)[:3, 3])
        # points whose most probable class is dynamic (people) only clear free space: they leave by pixel, before
        # anything else is gathered for them (a network calls a few pixels of most frames a person)
        flat = semantics.reshape_flat() if semantics is not None else None
        clear = None
        if self._is_dynamic is not None and flat is not None:
            moving = self._is_dynamic[np.take(flat.labels[:, 0], pixels)]
            if moving.any():
                keep = np.flatnonzero(~moving)  # (np.take: a third of what fancy indexing costs on (N, 3) rows)
                clear, points_world = points_world[moving], np.take(points_world, keep, axis=0)
                pixels = np.take(pixels, keep)
                self.points_cleared += len(clear)
        # colour and class set of each point's pixel
        colors = np.take(frame.rgb.reshape(-1, 3), pixels, axis=0)
        point_sem = None
        if flat is not None:
            point_sem = TopKProbs(np.take(flat.labels, pixels, axis=0), np.take(flat.probs, pixels, axis=0))
        # keyframes (the camera moved 10 cm or turned 10° since the last one) and, on them, normals if a map asks
        keyframe = self._keyframe_of.due(T_world_cam)
        self.keyframes += keyframe
        self.last_was_keyframe = keyframe
        normals = (pixel_normals(frame.depth, frame.intrinsics, T_world_cam, pixels)
                   if self._normals and keyframe else None)
        obs = Observation(points_world, np.asarray(T_world_cam, np.float64)[:3, 3].copy(), colors, point_sem,
                          normals=normals, frame_index=frame.index, keyframe=keyframe, clear_points=clear)
        ms = {"backproject": (time.perf_counter() - t0) * 1e3}
        # each map fuses the same observation (the OctoMap ray-casts free space from the camera centre)
        for i, m in enumerate(self.maps):
            steps = m.integrate(obs)
            ms.update(steps if i == 0 else {f"{m.kind.value}:{k}": v for k, v in steps.items()})
        if self.cloud is not None:  # the dense cloud keeps what the maps keep (no dynamic points)
            t_cloud = time.perf_counter()
            self.cloud.integrate_points(points_world, colors=colors)
            ms["cloud"] = (time.perf_counter() - t_cloud) * 1e3
        self.points_integrated += len(points_world) + (0 if clear is None else len(clear))  # (cleared ones too)
        self._check_growth(frame)
        return ms

    def dynamic_report(self, label_set: LabelSet | None) -> dict | None:
        """The dynamic classes by name and the points of theirs that only cleared free space (None: no class)."""
        if not self.dynamic or label_set is None:
            return None
        return {"classes": [label_set.names[c] for c in self.dynamic], "points_cleared": self.points_cleared}

    def _check_growth(self, frame: Frame) -> None:
        """After each frame, refuse to go on once the maps would pass the memory budget with one more frame like
        it (the first view's estimate cannot see a long or wide sequence coming)."""
        held = sum(int(getattr(m, "memory_bytes", 0)) for m in self.maps)
        held += self.cloud.memory_bytes if self.cloud is not None else 0
        growth, self._held = held - self._held, held
        check_map_growth(self.maps[0].resolution, held, growth, f"frame {frame.name or frame.index}")

    def _check_extent(self, points: np.ndarray, origin: np.ndarray) -> None:
        """Refuse a resolution whose ray-cast cells over the first frame's view (a cheap lower bound of the
        scene) would not fit the memory budget, before the OctoMap allocates them."""
        for m in self.maps:
            if m.kind == MapKind.OCTOMAP:
                extent = np.ptp(np.vstack([points.min(0), points.max(0), origin]), axis=0)
                box_cells = check_map_extent(m.resolution, tuple(extent), "the first frame's view")
                cells = box_cells / 3  # a view's rays fill about a third of its bounding box (a pyramid in its box)
                if cells > SLOW_VIEW_CELLS:
                    log.warning("--resolution %g: one view spans about %.0f million voxels (about %s); expect "
                                "minutes per frame and for writing the map files (--resolution %g: 8x fewer)",
                                m.resolution, cells / 1e6, human(cells * BYTES_PER_VOXEL), 2 * m.resolution)

    def state(self) -> tuple[dict, dict[str, np.ndarray]]:
        """A checkpoint's mapper: its counters and keyframe schedule (the maps save their own state)."""
        arrays = self._keyframe_of.state()
        if self.cloud is not None:
            arrays.update(prefixed("cloud", self.cloud.state()))
        return ({"points_integrated": self.points_integrated, "keyframes": self.keyframes,
                 "last_was_keyframe": self.last_was_keyframe, "points_cleared": self.points_cleared}, arrays)

    def restore(self, meta: dict, arrays: dict[str, np.ndarray]) -> None:
        """Continue from :meth:`state`."""
        self.points_integrated, self.keyframes = int(meta["points_integrated"]), int(meta["keyframes"])
        self.last_was_keyframe = bool(meta["last_was_keyframe"])
        self.points_cleared = int(meta.get("points_cleared", 0))
        self._keyframe_of.restore({k: v for k, v in arrays.items() if not k.startswith("cloud/")})
        if self.cloud is not None:
            self.cloud.restore(section(arrays, "cloud"))

    def integrate_arrays(self, rgb: np.ndarray, depth_m: np.ndarray, intrinsics: CameraIntrinsics | np.ndarray,
                         T_world_cam: np.ndarray, semantics: np.ndarray | TopKProbs | None = None, *, k: int = 3,
                         label_confidence: float = 0.9, index: int = 0) -> dict[str, float]:
        """:meth:`integrate` for a user's own loop: one frame as plain arrays (see
        :func:`semmap.frame_arrays.frame_from_arrays` and :func:`~semmap.frame_arrays.class_sets`)."""
        frame = frame_from_arrays(rgb, depth_m, intrinsics, T_world_cam=T_world_cam, index=index)
        classes = next((len(m.label_set) for m in self.maps if m.label_set is not None), None)
        sem = class_sets(semantics, frame.depth.shape, num_classes=classes, k=k, label_confidence=label_confidence)
        return self.integrate(frame, frame.T_world_cam, sem)


def dynamic_table(classes: Iterable[int]) -> np.ndarray | None:
    """(65536,) bool: is a point's top class (a uint16 id, EMPTY_LABEL included) dynamic; None when none is."""
    ids = np.asarray(list(classes), np.int64)
    if ids.size == 0:
        return None
    table = np.zeros(1 << 16, bool)
    table[ids] = True
    return table


def semantics_for(frame: Frame, source: SemanticSource, *, label_set: LabelSet | None, label_confidence: float,
                  k: int) -> TopKProbs | None:
    """Per-pixel class sets of a frame without a segmenter: the frame's own (a precomputed stream), its label
    image with a fixed confidence, or none."""
    if frame.semantics is not None:
        return frame.semantics
    if source == SemanticSource.NONE or label_set is None:
        return None
    if frame.labels is not None:
        return TopKProbs.from_hard_labels(frame.labels, label_confidence, len(label_set), k)
    return None


def semantics_fn(segmenter: Segmenter | None, config: RunConfig, label_set: LabelSet | None):
    """A frame's class sets as the run gets them (the segmenter's, else :func:`semantics_for`), as a function."""
    if segmenter is not None:
        return segmenter.segment
    s = config.semantics
    return lambda frame: semantics_for(frame, s.source, label_set=label_set, label_confidence=s.label_confidence,
                                       k=s.k)


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


def no_pose_hint(config: RunConfig, dataset: Dataset) -> str:
    """What to do when no frame has a pose: ground-truth poses come from the dataset (a bag's /tf or
    --pose-topic, a folder's ground-truth file); without them, a tracker estimates them."""
    if config.poses.source != GROUND_TRUTH:
        return ""
    from semmap.datasets.rosbag import RosbagDataset

    track = "estimate them with --poses slam or --poses odometry"
    if isinstance(dataset, RosbagDataset):
        return f" (the bag has no camera poses on /tf or a --pose-topic: {track})"
    return f" (poses come from the dataset's ground truth, e.g. TUM groundtruth.txt; without one, {track})"



def build_mapper(c: RunConfig, label_set, prior) -> Mapper:
    """The run's maps (continuing ``prior``'s state when there is one) in a mapper with the run's settings."""
    maps = [get_map(kind, c, label_set) for kind in c.mapping.maps]
    return Mapper(maps if prior is None else prior.restored(maps, label_set), min_depth=c.mapping.min_depth,
                  max_depth=c.mapping.max_depth, pixel_stride=c.mapping.pixel_stride,
                  cloud_resolution=c.mapping.point_resolution if c.output.cloud else None,
                  dynamic=dynamic_classes(c, label_set))

def frame_words(index: int, name: str | None) -> str:
    """``frame 41 of the sequence (1.333333)``: a frame by its place in the sequence, counted from 1, and by its
    name (a TUM frame's timestamp) when it has one."""
    return f"frame {index + 1} of the sequence" + (f" ({name})" if name and name != str(index) else "")


class Pipeline:
    """One mapping run from a dataset to ``map.ot``, ``map.bt``, ``map.semmap``, previews and the report.

    ``run()`` is a short list of steps: stage the outputs, get ready (``run.prepare``), map every frame (the frame
    loop below, the only part of a run that lives here), then write the files (``run.outputs``) and the report
    (``eval.run_report``) and move them into ``--out`` at once."""

    def __init__(self, config: RunConfig, *, segmenter: Segmenter | None = None, progress: Progress | None = None,
                 dataset: Dataset | None = None, ground_truth: GroundTruthFn | None = None,
                 title: str = "semmap run", track_progress: Progress | None = None,
                 instances: InstanceSource | None = None, checkpoint_every: int = 0, resume: bool = False,
                 prior: PriorRun | None = None):
        self.config, self.prior = config, prior  # prior: the finished run this one continues (--continue)
        self.checkpoint_every, self.resume = int(checkpoint_every), bool(resume)
        self.segmenter = segmenter
        self.instances = instances  # an instance source builds the object map beside the maps
        self.progress = progress or (lambda it, n: it)
        self.track_progress = track_progress
        self.dataset = dataset
        self.title = title
        self.scorer = RunScorer(ground_truth, config.mapping.resolution)
        self._objects: ObjectStage | None = None
        self._viewer: Visualizer = NoVisualizer()
        self._checkpoints: Checkpoints | None = None
        self._empty_frames = 0  # frames without a depth pixel in range

    def run(self) -> RunResult:
        """Map the sequence; outputs appear in ``--out`` all at once at the end (a failure or Ctrl-C leaves it as it
        was, and with checkpoints the staging folder to ``--resume`` from)."""
        check_run_paths(self.config)  # --out and --rerun against every input, before any work
        check_checkpoint_options(self.checkpoint_every, self.resume, online=self.config.mode == LoopMode.ONLINE,
                                 objects=self.instances is not None,
                                 batched=self.segmenter is not None and self.config.semantics.batch_size > 1)
        staged = StagedRun(self.config.output.out, resume=self.resume)
        with deferred_interrupts():
            stage = staged.open()
            self._checkpoints = Checkpoints(staged, self.config, every=self.checkpoint_every)
            try:
                outcome = self._map(stage)
                report = self._write(outcome)
                staged.commit()  # every file is there: the folder becomes --out in one rename
            except RunInterrupted as exc:
                raise RunInterrupted(f"{exc}; {staged.abandon(keep_checkpoint=True)}") from None
            except BaseException:
                staged.abandon(keep_checkpoint=self.checkpoint_every > 0 or self.resume)
                raise
            final = self.config.output.out
            if stop_requested():  # Ctrl-C after the last frame: the outputs were finished, and are kept
                log.warning("Ctrl-C after the last frame: the run finished writing; its outputs in %s are complete",
                            final)
            files = {key: final / Path(path).relative_to(stage) for key, path in outcome.files.items()}
            return RunResult(list(outcome.maps), final, report, files, outcome.record.poses)

    # ---------------------------------------------------------------- steps
    def _map(self, stage: Path) -> RunOutcome:
        """Get ready, map every frame, refine, write the maps' files; what the report is made from."""
        c = self.config
        self._viewer = get_visualizer(staged_output(c.output, stage), name=self.title)  # (--rerun in --out: staged)
        dataset = self.dataset if self.dataset is not None else open_dataset_of(c.input)
        label_set = label_set_for(c, dataset, self.segmenter)
        startup_s = compile_kernels(c.mapping.maps)  # numba's first-use compilation out of the per-frame timings
        first = FirstFrame(dataset)  # what a segmenter and an online tracker get ready on (read if needed)
        check_labels_exist(c, dataset, first, self.segmenter)
        segmenter_s = prepare_segmenter(self.segmenter, first)  # and an ONNX export / session out of the first frame's
        mapper = build_mapper(c, label_set, self.prior)
        resumed = (self._checkpoints.resume(mapper, lambda: pose_source_to_resume(c, dataset)) if self.resume
                   else None)
        if resumed is not None:  # the maps, poses and sums of the last checkpoint; its frames are not read again
            pose_of, record = resumed
        else:
            pose_of = pose_source_for(c, dataset, instances=self.instances, track_progress=self.track_progress)
            record = RunRecord()
        continued = (None if self.prior is None
                     else self.prior.align(dataset, pose_of, semantics_fn(self.segmenter, c, label_set), c.mapping))
        pose_of.limit_to(TREE_MAX_VAL * c.mapping.resolution)  # (the key range of every map)
        startup_s += warm_tracker(c, first)
        self._objects = ObjectStage(self.instances) if self.instances is not None else None
        if self._objects is not None:
            self._viewer.show_objects(self._objects.map.real_objects, self._objects.map.label_set)
        self._integrate_all(dataset, mapper, label_set, pose_of, record)
        maps = mapper.maps
        self._viewer.finish(maps[0])
        warn_if_empty(maps[0], c, mapper.points_integrated, record.poses)
        self.scorer.align_to(pose_of)  # maps from estimated poses are scored in the ground truth's frame
        crf = (refine_maps(maps, record.poses, params=c.crf.params(), scorer=self.scorer)
               if c.crf.enabled else {})
        files, sizes = write_outputs(stage, maps, record.poses, c, self._objects, cloud=mapper.cloud)
        return RunOutcome(record=record, maps=maps, pose_of=pose_of, dataset=str(c.input.dataset),
                          skipped=list(dataset.skipped), points_integrated=mapper.points_integrated, sizes=sizes,
                          cloud_points=None if mapper.cloud is None else mapper.cloud.num_voxels,
                          cloud_cell_m=None if mapper.cloud is None else mapper.cloud.resolution,
                          files=files, out_dir=stage, online=c.mode == LoopMode.ONLINE,
                          segmenter=None if self.segmenter is None else self.segmenter.name, startup_s=startup_s,
                          segmenter_startup_s=segmenter_s, crf=crf,
                          semantics=semantics_source(c, self.segmenter, label_set, dataset.label_set),
                          realism=simulated_realism(dataset, c.input.dataset),
                          objects=None if self._objects is None else self._objects.report(mapper.keyframes),
                          dynamic=mapper.dynamic_report(label_set), continued=continued)

    def _write(self, outcome: RunOutcome) -> dict:
        """The report of the run (``report.json``, ``.md``, ``.html``, plots) into the staging folder."""
        report = build_report(outcome, self.scorer, self.config.mapping.resolution)
        outcome.files.update(write_report(outcome.out_dir, report, title=self.title, plots=self.config.output.plots,
                                          used=outcome.pose_of.used_trajectory(),
                                          ground_truth=outcome.pose_of.ground_truth(), primary=outcome.maps[0]))
        return report

    # ---------------------------------------------------------------- the frame loop
    def _integrate_all(self, dataset: Dataset, mapper: Mapper, label_set: LabelSet | None, pose_of: FramePoses,
                       record: RunRecord) -> None:
        """The frame loop: frames (loaded, posed) -> semantics -> every map, one frame at a time in order.

        Offline, poses are the tracker's final trajectory (tracked in a pass before) and due frames are segmented
        in batches; online, each frame is tracked as it arrives and due frames are segmented on a thread beside
        tracking. Either way ``_integrate_frame`` sees the same frames in the same order."""
        record.timings = defaultdict(float, record.timings)  # (a checkpoint stores it as a plain dict)
        t0 = time.perf_counter() - record.seconds
        with self._semantic_stream(self._posed_frames(dataset, pose_of, record), label_set, record) as stream:
            for frame, T, sem in stream:
                self._integrate_frame(frame, T, sem, mapper, label_set, record)
                self._after_frame(frame, mapper, pose_of, record)
        record.seconds = time.perf_counter() - t0
        no_pose = record.no_pose
        if not record.poses:
            hint = no_pose_hint(self.config, dataset) if no_pose else ""
            if pose_of.beyond_reach:
                hint = (f" ({pose_of.beyond_reach} cameras lie beyond the ±{pose_of.reach_m:,.0f} m the maps can hold "
                        f"at --resolution {self.config.mapping.resolution:g} m: check the poses and their unit)")
            raise ConfigError(f"{self.config.input.dataset}: no frame could be mapped "
                              f"({len(dataset.skipped)} unreadable, {len(no_pose)} without pose){hint}")
        if len(no_pose) > 1:
            log.warning("%d frames had no pose and were skipped (%s ... %s)", len(no_pose), no_pose[0], no_pose[-1])

    @contextmanager
    def _semantic_stream(self, posed: Iterator[tuple[Frame, np.ndarray]], label_set: LabelSet | None,
                         record: RunRecord) -> Iterator[Iterable[tuple[Frame, np.ndarray, TopKProbs | None]]]:
        """``(frame, T, semantics or None)`` in frame order: segmented as the schedule says (in batches offline,
        on a worker thread beside tracking online), or from the frames' own labels."""
        s = self.config.semantics
        if self.segmenter is None:
            yield ((f, T, semantics_for(f, s.source, label_set=label_set, label_confidence=s.label_confidence,
                                        k=s.k)) for f, T in posed)
            return
        if record.scheduler is None:  # (a resumed run continues the checkpoint's schedule)
            record.scheduler = Scheduler(SegmentationSchedule(every=s.segment_every, keyframes=s.keyframes))
        if self.config.mode == LoopMode.OFFLINE:
            yield with_semantics(posed, self.segmenter, record.scheduler, batch_size=s.batch_size,
                                 timings=record.timings)
            return
        o = self.config.online
        with SegmentationWorker(self.segmenter, max_queued=o.segment_queue,
                                numba_threads=o.segment_numba_threads) as worker:
            yield with_semantics_beside(posed, worker, record.scheduler, max_pending=o.max_pending,
                                        timings=record.timings)

    def _integrate_frame(self, frame: Frame, T: np.ndarray, sem: TopKProbs | None, mapper: Mapper,
                         label_set: LabelSet | None, record: RunRecord) -> None:
        """One frame into every map (and the object map, the CRF and the viewer), the moment its pose and
        semantics are there; its latency since it was read."""
        timings = record.timings
        temperature = self.config.semantics.temperature
        if sem is not None and temperature != 1.0:  # --temperature: softened or sharpened before anything uses it
            t_temp = time.perf_counter()
            sem = apply_temperature(sem, temperature, num_classes=None if label_set is None else len(label_set))
            timings["temperature"] += (time.perf_counter() - t_temp) * 1e3
        if self.segmenter is not None and sem is not None:
            record.segmented += 1
            if frame.labels is not None:
                self.scorer.add_segmentation(record, sem, frame.labels, len(label_set))
        if frame.labels is not None and label_set is not None and record.pixels.due(len(record.poses)):
            t_px = time.perf_counter()  # the frame's pixels and the maps' labels there before it is fused
            record.pixels.add(frame, T, sem, mapper.maps, min_depth=mapper.min_depth, max_depth=mapper.max_depth)
            timings["eval_pixels"] += (time.perf_counter() - t_px) * 1e3
        before = mapper.points_integrated
        for name, ms in mapper.integrate(frame, T, sem).items():
            timings[name] += ms
        if mapper.points_integrated == before:
            self._warn_empty_frame(frame)
        if self._objects is not None:  # instances and tracks every frame, the object map on keyframes
            t_obj = time.perf_counter()
            self._objects.step(frame, T, sem, mapper.last_was_keyframe)
            timings["objects"] += (time.perf_counter() - t_obj) * 1e3
        every = self.config.crf.every
        if self.config.crf.enabled and every and mapper.last_was_keyframe and mapper.keyframes % every == 0:
            t_crf = time.perf_counter()
            refine_maps(mapper.maps, [*record.poses, T], params=self.config.crf.params(),
                        scorer=self.scorer)
            timings["crf"] += (time.perf_counter() - t_crf) * 1e3
        record.poses.append(T)
        record.latency_ms.append((time.perf_counter() - record.arrival.pop(id(frame))) * 1e3)
        self._viewer.log_frame(frame, T, sem, mapper.maps[0])

    def _warn_empty_frame(self, frame: Frame) -> None:
        """Say which frames add nothing to the map (the first few by name, then that there are more)."""
        self._empty_frames += 1
        m = self.config.mapping
        if self._empty_frames <= MAX_EMPTY_FRAME_WARNINGS:
            log.warning("frame %s adds nothing to the map: no depth pixel lies between --min-depth %g and "
                        "--max-depth %g m%s", frame.name, m.min_depth, m.max_depth,
                        "" if self._empty_frames < MAX_EMPTY_FRAME_WARNINGS else " (further such frames not listed)")

    def _after_frame(self, frame: Frame, mapper: Mapper, pose_of: FramePoses, record: RunRecord) -> None:
        """Checkpoint every ``checkpoint_every`` mapped frames (and on Ctrl-C), then stop here if asked to."""
        record.last_index, record.last_name = int(frame.index), frame.name
        interrupted = stop_requested()
        self._checkpoints.after_frame(frame, mapper, pose_of, record, interrupted=interrupted)
        if interrupted:
            raise RunInterrupted(f"interrupted after {frame_words(frame.index, frame.name)}, {len(record.poses)} "
                                 f"frames mapped")

    def _posed_frames(self, dataset: Dataset, pose_of: FramePoses, record: RunRecord):
        """``(frame, T_world_cam)`` for every readable frame with a pose, behind the progress bar; frames
        without a pose are warned about and listed in ``record.no_pose``.  Online, the next frames are read on a
        thread meanwhile and the tracker runs here.  ``load`` is the time the loop waited for a frame."""
        after, timings = record.last_index, record.timings  # frames up to ``after`` are in the checkpoint's maps
        with self._arrivals(dataset) as arrivals:
            t_wait = time.perf_counter()
            for frame, arrived in self.progress(arrivals, len(dataset)):
                if stop_requested():
                    last = ("no frame" if record.last_index is None
                            else frame_words(record.last_index, record.last_name))
                    raise RunInterrupted(f"interrupted after {last}, {len(record.poses)} frames mapped")
                if after is not None and frame.index <= after:
                    t_wait = time.perf_counter()
                    continue
                t_pose = time.perf_counter()
                timings["load"] += (t_pose - t_wait) * 1e3
                T, reason = pose_of(frame)
                if pose_of.tracker is not None:
                    timings["track"] += (time.perf_counter() - t_pose) * 1e3
                if T is None:  # the first one is a warning; the rest are counted (one line at the end)
                    (log.debug if record.no_pose else log.warning)("frame %s has no pose (%s); skipped", frame.name,
                                                                   reason)
                    record.no_pose.append(frame.name)
                else:
                    record.arrival[id(frame)] = arrived
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
