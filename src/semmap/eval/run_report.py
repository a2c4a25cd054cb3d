"""The report of one mapping run, assembled beside the frame loop from one record of the run.

The frame loop (``semmap.pipeline``) keeps a :class:`RunRecord` and nothing else; :class:`RunScorer` holds the
accuracy against ground truth (the segmenter per pixel, every map per voxel); :func:`build_report` turns both,
the maps and the pose source into ``report.json``'s dict, and :func:`write_report` writes it with ``report.md``,
``report.html`` and the plots.
"""

from __future__ import annotations

import json
import logging
from collections import defaultdict
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from semmap.errors import ConfigError
from semmap.eval.pixels import PixelRecord
from semmap.eval.report_html import write_report_html
from semmap.eval.report_md import write_report_md
from semmap.eval.report_plots import write_report_plots
from semmap.eval.semantic import confusion, evaluate_2d, evaluate_cloud_3d
from semmap.files.atomic import write_text_atomic
from semmap.limits import MemoryBudgetError
from semmap.maps.base import SemanticMap
from semmap.maps.registry import MAPS, MapKind
from semmap.perception.schedule import Scheduler, SegmentationSchedule
from semmap.poses.base import LiveTracker
from semmap.poses.frame_poses import FramePoses
from semmap.poses.track import GROUND_TRUTH
from semmap.types import TopKProbs, Trajectory, rotation_angle, transform_points
from semmap.viz.web_view import ViewContent

log = logging.getLogger("semmap")
#: Ground truth for 3D evaluation: resolution -> (keys (M, 3), class ids (M,)) of the true surface voxels.
GroundTruthFn = Callable[[float], tuple[np.ndarray, np.ndarray]]


@dataclass
class RunRecord:
    """What the frame loop keeps: the poses frames were mapped with (in order), when each waiting frame was read,
    each frame's latency from being read to being in the maps, the loop's wall time and per-step milliseconds,
    frames without a pose, the segmenter's frames and confusion against ground truth, the segmentation schedule's
    own state and the last frame mapped (a checkpoint saves all of it, so ``--resume`` continues exactly)."""

    poses: list[np.ndarray] = field(default_factory=list)
    arrival: dict[int, float] = field(default_factory=dict)
    latency_ms: list[float] = field(default_factory=list)
    seconds: float = 0.0
    timings: dict[str, float] = field(default_factory=lambda: defaultdict(float))
    no_pose: list[str] = field(default_factory=list)
    segmented: int = 0
    conf2d: np.ndarray | None = None
    scheduler: Scheduler | None = None
    last_index: int | None = None  # dataset index of the last frame mapped
    last_name: str | None = None
    pixels: PixelRecord = field(default_factory=PixelRecord)  # the map-at-pixel samples (``eval.pixels``)

    def __post_init__(self) -> None:
        self.timings = defaultdict(float, self.timings)

    def state(self) -> tuple[dict, dict[str, np.ndarray]]:
        """A checkpoint's record: JSON-able sums and names, and arrays (poses, latencies, confusion, schedule)."""
        meta = {"seconds": self.seconds, "timings": dict(self.timings), "no_pose": list(self.no_pose),
                "segmented": self.segmented, "last_index": self.last_index, "last_name": self.last_name,
                "scheduled": self.scheduler is not None, "scored": self.conf2d is not None}
        arrays = {"poses": np.asarray(self.poses, np.float64).reshape(-1, 4, 4),
                  "latency_ms": np.asarray(self.latency_ms, np.float64)}
        if self.conf2d is not None:
            arrays["conf2d"] = self.conf2d
        if self.scheduler is not None:
            arrays.update({f"schedule/{k}": v for k, v in self.scheduler.state().items()})
        arrays.update({f"pixels/{k}": v for k, v in self.pixels.state().items()})
        return meta, arrays

    @classmethod
    def from_state(cls, meta: dict, arrays: dict[str, np.ndarray], schedule: SegmentationSchedule) -> RunRecord:
        """The record :meth:`state` saved (its segmentation schedule continued with ``schedule``'s settings)."""
        record = cls(poses=list(np.asarray(arrays["poses"], np.float64)),
                     latency_ms=[float(v) for v in arrays["latency_ms"]], seconds=float(meta["seconds"]),
                     timings={str(k): float(v) for k, v in dict(meta["timings"]).items()},
                     no_pose=[str(n) for n in meta["no_pose"]], segmented=int(meta["segmented"]),
                     conf2d=arrays["conf2d"] if meta["scored"] else None, last_index=meta["last_index"],
                     last_name=meta["last_name"])
        if meta["scheduled"]:
            record.scheduler = Scheduler(schedule)
            record.scheduler.restore({k.removeprefix("schedule/"): v for k, v in arrays.items()
                                      if k.startswith("schedule/")})
        if "pixels/sizes" in arrays:
            record.pixels.restore({k.removeprefix("pixels/"): v for k, v in arrays.items() if k.startswith("pixels/")})
        return record


class RunScorer:
    """Accuracy of a run against ground truth: the segmenter's per-pixel confusion (into the record) and each
    map's voxels at the run's resolution (ground-truth voxels computed once per resolution), in the ground truth's
    frame: a map built from estimated poses is moved there first (:meth:`align_to`)."""

    def __init__(self, ground_truth: GroundTruthFn | None, resolution: float) -> None:
        self.ground_truth, self.resolution = ground_truth, resolution
        self._gt: dict[float, tuple[np.ndarray, np.ndarray]] = {}
        self.T_gt_map: np.ndarray | None = None  # the map's frame onto the ground truth's (None: already there)
        self.alignment: dict | None = None  # how T_gt_map was found, for the report
        self._aligned = False
        self._frame_unknown = False  # estimated poses without a ground-truth trajectory to align them to

    def align_to(self, pose_of: FramePoses) -> None:
        """Find (once) where the map lies against the ground truth: in its frame with ground-truth poses; otherwise
        moved by the ATE's SE(3) alignment of the poses used onto the frames' ground truth. A map that cannot be
        aligned is not scored in 3D (a score in the wrong frame would be meaningless), with a warning."""
        if self._aligned or pose_of.source == GROUND_TRUTH:
            self._aligned = True
            return
        self._aligned = True
        gt = pose_of.ground_truth()
        if len(gt) == 0 and self.ground_truth is None:
            return  # nothing to align to and nothing to score
        from semmap.eval.trajectory import alignment_to_ground_truth

        try:
            if len(gt) == 0:
                raise ConfigError("the frames have no ground-truth poses")
            T, how = alignment_to_ground_truth(gt, pose_of.used_trajectory())
        except ConfigError as exc:
            self._frame_unknown = True
            self.alignment = {"method": "none", "why": str(exc)}
            if self.ground_truth is not None:
                log.warning("the map is not scored in 3D: its %s poses cannot be aligned to the ground truth (%s)",
                            pose_of.source, exc)
            return
        self.T_gt_map = T
        self.alignment = {**how, "T_gt_map": T.round(9).tolist()}

    @staticmethod
    def add_segmentation(record: RunRecord, sem: TopKProbs, gt_labels: np.ndarray, num_classes: int) -> None:
        """Accumulate the per-pixel confusion of the segmenter's top class against ground-truth labels."""
        conf = confusion(sem.labels[..., 0], gt_labels, num_classes)
        record.conf2d = conf if record.conf2d is None else record.conf2d + conf

    def map_3d(self, m: SemanticMap) -> dict:
        """3D accuracy of a map at the run's voxel size (a finer point map votes per voxel), its points moved onto
        the ground truth by :attr:`T_gt_map`; empty without ground truth, classes or a known frame."""
        if self.ground_truth is None or m.label_set is None or self._frame_unknown:
            return {}
        if self.resolution not in self._gt:
            try:
                self._gt[self.resolution] = self.ground_truth(self.resolution)
            except MemoryBudgetError as exc:  # a score is not worth running out of memory for: warn, go on
                log.warning("the map is not scored in 3D: %s", exc)
                self.ground_truth = None
                return {}
        gt_keys, gt_labels = self._gt[self.resolution]
        cloud = m.cloud()
        centers = cloud.centers if self.T_gt_map is None else transform_points(self.T_gt_map, cloud.centers)
        return evaluate_cloud_3d(centers, cloud.labels, gt_keys, gt_labels, m.label_set, self.resolution)

    def evaluate(self, primary: SemanticMap, record: RunRecord, segmenter_name: str | None) -> dict:
        """Accuracy against ground truth when there is any: the segmenter per pixel, then the map's voxels."""
        if primary.label_set is None:
            return {}
        out: dict = {}
        if record.conf2d is not None and segmenter_name is not None:
            out.update(evaluate_2d(record.conf2d, primary.label_set, segmenter_name))
        out.update(self.map_3d(primary))
        return out


def files_of(m: SemanticMap) -> set[str]:
    """Names of the files a map's save writes (the OctoMap's map.*; other maps <kind>.*), and its preview."""
    return MAPS[m.kind].files()


def maps_report(maps: Sequence[SemanticMap], sizes: dict[str, int], crf: dict[MapKind, dict],
                scorer: RunScorer, pixels: PixelRecord | None = None) -> dict:
    """Each map side by side: what it holds, its files, its accuracy (and before the CRF), at voxels and at the
    evaluated frames' pixels."""
    out = {}
    for m in maps:
        files = {name: size for name, size in sizes.items() if name in files_of(m)}
        entry = {"resolution": m.resolution, **m.describe(), "files": files, **scorer.map_3d(m),
                 **(pixels.report(m) if pixels is not None else {})}
        if m.kind in crf:
            entry["crf"] = crf[m.kind]
        out[m.kind.value] = entry
    return out


def semantics_summary(primary: SemanticMap, segmenter_name: str | None, segmented: int) -> dict:
    """Segmenter, frames segmented and occupied voxels per most probable class (classes with voxels)."""
    out: dict = {}
    if segmenter_name is not None:
        out["segmenter"] = segmenter_name
        out["frames_segmented"] = segmented
    if primary.label_set is not None:
        top = primary.cloud().labels
        names = primary.label_set.names
        counts = np.bincount(top[top < len(names)].astype(np.int64), minlength=len(names))
        order = np.argsort(-counts, kind="stable")
        out["voxels_per_class"] = {names[i]: int(counts[i]) for i in order if counts[i] > 0}
        out["voxels_without_class"] = int((top >= len(names)).sum())
    return out


def trajectory_report(pose_of: FramePoses, out_dir: Path, files: dict[str, Path]) -> dict:
    """Write the poses used into ``trajectory.txt``; score them against ground truth when there is one."""
    from semmap.io.trajectory import write_trajectory

    out: dict = {"poses": pose_of.source}
    used = pose_of.used_trajectory()
    if len(used):
        files["trajectory"] = write_trajectory(out_dir / "trajectory.txt", used)
    if pose_of.tracking_s is not None:
        out["tracking_ms_per_frame"] = round(1e3 * pose_of.tracking_s / max(pose_of.tracked, 1), 2)
    if pose_of.edge_stats is not None:
        out["object_pose_edges"] = pose_of.edge_stats
    if pose_of.source != GROUND_TRUTH:
        scores = _scored_against_ground_truth(pose_of.ground_truth(), used, "the trajectory used")
        if scores is not None:
            out["trajectory_vs_ground_truth"] = scores
    return out


def _scored_against_ground_truth(gt: Trajectory, est: Trajectory, what: str) -> dict | None:
    """ATE, RPE and matched poses of ``est`` against ``gt`` (at least 3 poses each); None, with a warning, where
    they cannot be aligned (a camera that never moved): no score, not a failed run."""
    if len(gt) < 3 or len(est) < 3:
        return None
    from semmap.eval.trajectory import evaluate_trajectory

    try:
        scores = evaluate_trajectory(gt, est)
    except ConfigError as exc:
        log.warning("%s is not scored: %s", what, exc)
        return None
    return {k: scores[k] for k in ("ate_rmse_m", "rpe_trans_m", "matched") if k in scores}


def online_report(record: RunRecord, pose_of: FramePoses, resolution: float, out_dir: Path,
                  files: dict[str, Path]) -> dict:
    """Frame rate and latency of the online loop, and the drift its map keeps: how far each frame's final,
    loop-closed pose lies from the pose it was mapped with (``trajectory_final.txt``; mapping it again,
    offline, is ``--poses trajectory_final.txt``)."""
    lat = np.asarray(record.latency_ms)
    out: dict = {"fps": round(len(record.poses) / max(record.seconds, 1e-9), 2), "loop_s": round(record.seconds, 2),
                 "latency_ms": {"median": round(float(np.median(lat)), 1),
                                "p95": round(float(np.percentile(lat, 95)), 1), "max": round(float(lat.max()), 1)}}
    if pose_of.tracker is None:
        return {**out, "drift_left_in": drift_left_in(pose_of.used_trajectory(), pose_of.used_trajectory(),
                                                       resolution)}
    from semmap.io.trajectory import write_trajectory

    final = pose_of.tracker.trajectory()
    files["trajectory_final"] = write_trajectory(out_dir / "trajectory_final.txt", final)
    if isinstance(pose_of.tracker, LiveTracker):
        out["loop_closures"] = pose_of.tracker.loop_closures
    out["drift_left_in"] = drift_left_in(pose_of.used_trajectory(), final, resolution)
    scores = _scored_against_ground_truth(pose_of.ground_truth(), final, "the final trajectory")
    if scores is not None:
        out["final_trajectory_vs_ground_truth"] = scores
    return out


@dataclass
class RunOutcome:
    """Everything a finished frame loop hands to the report: the record, the maps (primary first), the pose
    source, the dataset's name and unreadable frames, what was written, and start-up costs."""

    record: RunRecord
    maps: Sequence[SemanticMap]
    pose_of: FramePoses
    dataset: str
    skipped: list  # SkippedFrame entries of the dataset
    points_integrated: int
    sizes: dict[str, int]
    files: dict[str, Path]
    out_dir: Path
    online: bool
    segmenter: str | None = None
    startup_s: float = 0.0
    segmenter_startup_s: float = 0.0
    crf: dict[MapKind, dict] = field(default_factory=dict)
    objects: dict | None = None
    semantics: str | None = None  # where the classes came from, in words (``run.prepare.semantics_source``)
    cloud_points: int | None = None  # points of the dense coloured cloud written as ``cloud.ply`` (None: none)
    cloud_cell_m: float | None = None  # its voxel filter's cell (m)
    dynamic: dict | None = None  # the dynamic classes and the points that only cleared free space (None: no class)
    continued: dict | None = None  # --continue: the prior and how the recording was aligned to it
    realism: str | None = None  # the simulator's realism preset of simulated frames (None: recorded data)


def _frames_report(o: RunOutcome) -> dict:
    """What was mapped, what it holds and costs, per frame and on disk."""
    n = len(o.record.poses)
    primary = o.maps[0]
    ms = {k: round(v / n, 3) for k, v in o.record.timings.items()}
    # online, segmentation runs on its own thread: the loop pays only the time it waits for it
    beside = {"segment"} if o.online else set()
    ms["total"] = round(sum(v for k, v in ms.items() if k not in beside), 3)
    return {
        "dataset": o.dataset,
        **({} if o.realism is None else {"realism": o.realism}),
        "resolution": primary.resolution,
        "frames_used": n,
        "frames_skipped": len(o.skipped) + len(o.record.no_pose),
        "skipped": [{"name": s.name, "path": s.path, "reason": s.reason} for s in o.skipped]
        + [{"name": name, "path": "", "reason": "no pose"} for name in o.record.no_pose],
        **primary.describe(),
        "bytes_on_disk": o.sizes,
        **_cloud_report(o),
        "points_integrated": o.points_integrated,
        "ms_per_frame": ms,
        "label_set": None if primary.label_set is None else len(primary.label_set),
        **({} if o.semantics is None else {"semantics": o.semantics}),
        **semantics_summary(primary, o.segmenter, o.record.segmented),
    }


def _cloud_report(o: RunOutcome) -> dict:
    """The dense coloured cloud as written (``cloud.ply``): its real size in bytes and its points."""
    if o.cloud_points is None or "cloud.ply" not in o.sizes:
        return {}
    return {"dense_point_cloud_bytes": o.sizes["cloud.ply"], "dense_point_cloud_points": o.cloud_points,
            **({} if o.cloud_cell_m is None else {"dense_point_cloud_cell_m": o.cloud_cell_m})}


def build_report(o: RunOutcome, scorer: RunScorer, resolution: float) -> dict:
    """``report.json``'s dict of a finished run (writes ``trajectory.txt`` / ``trajectory_final.txt`` on the way)."""
    scorer.align_to(o.pose_of)  # (once: a run with the CRF aligned before scoring the maps before it)
    report = _frames_report(o)
    report["startup_s"] = round(o.startup_s + o.segmenter_startup_s, 3)
    if o.segmenter is not None:
        report["segmenter_startup_s"] = round(o.segmenter_startup_s, 3)
    report.update(trajectory_report(o.pose_of, o.out_dir, o.files))
    if o.continued is not None:
        report["continued"] = o.continued
    if scorer.alignment is not None:  # the map's frame against the ground truth's, as the 3D scores and plot use it
        report["map_alignment"] = scorer.alignment
    report["peak_rss_mb"] = round(peak_rss_mb(), 1)
    # frames per second of the work a frame needs (the tracking pass before, offline, and the frame loop)
    before = (o.pose_of.tracking_s or 0.0) if o.pose_of.tracker is None else 0.0  # online it is inside the loop
    report["frames_per_second"] = round(len(o.record.poses) / max(o.record.seconds + before, 1e-9), 2)
    if o.online:
        report["online"] = online_report(o.record, o.pose_of, resolution, o.out_dir, o.files)
    if o.objects is not None:
        report["objects"] = o.objects
    if o.dynamic is not None:
        report["dynamic"] = o.dynamic
    primary = o.maps[0]
    report.update(scorer.evaluate(primary, o.record, o.segmenter))
    report.update(o.record.pixels.report(primary))  # the map against the network at the same pixels
    if primary.kind in o.crf and "miou_3d_before" in o.crf[primary.kind]:
        report["miou_3d_before_crf"] = o.crf[primary.kind]["miou_3d_before"]
    if len(o.maps) > 1 or o.crf:
        report["maps"] = maps_report(o.maps, o.sizes, o.crf, scorer, o.record.pixels)
    return report


def write_report(out_dir: Path, report: dict, *, title: str, plots: bool, used: Trajectory,
                 ground_truth: Trajectory, primary: SemanticMap) -> dict[str, Path]:
    """``report.json``, ``report.md``, ``report.html`` and (with ``plots``) the report's figures; their paths."""
    write_text_atomic(out_dir / "report.json", json.dumps(report, indent=2))
    figures = (write_report_plots(out_dir, report, used=used, ground_truth=ground_truth, cloud=primary.cloud())
               if plots else {})
    view, shown = _map_view(out_dir, primary, used) if plots else (None, None)
    write_report_md(out_dir / "report.md", report, title=title, plots=figures, map_view=shown)
    write_report_html(out_dir / "report.html", (out_dir / "report.md").read_text(), title=title, map_view=view)
    files = {"report": out_dir / "report.json", "report_md": out_dir / "report.md",
             "report_html": out_dir / "report.html"}
    files.update({f"plot_{name}": out_dir / file for name, file in figures.items()})
    return files


def _map_view(out_dir: Path, primary: SemanticMap, used: Trajectory) -> tuple[str, ViewContent]:
    """report.html's 3D view of the primary map, with the run's objects (``objects.json``, already written) and
    camera path: the HTML to embed and what it shows."""
    from semmap.viz.web_view import figure_of, run_extras, view_html

    objects, _ = run_extras(out_dir)
    fig, shown = figure_of(primary.cloud(), primary.label_set, objects=objects, poses=used.poses,
                           title=f"the {primary.kind.value} map in 3D")
    return view_html(fig, full_html=False), shown


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

