"""Getting a run ready before its first frame: the label set of the maps, where each frame's pose comes from
(a tracker's pass over the sequence, offline), and warm kernels so that the first frame's latency is honest."""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path

from semmap.config import DEFAULT_DYNAMIC, LoopMode, RunConfig, SemanticSource
from semmap.datasets import Dataset
from semmap.errors import ConfigError
from semmap.files.safe import path_kind
from semmap.interrupt import checked
from semmap.perception.base import Preparable, Segmenter
from semmap.perception.instances.base import InstanceSource
from semmap.perception.precomputed import FALLBACK_CLASSES
from semmap.poses.base import Progress
from semmap.poses.frame_poses import FramePoses
from semmap.poses.track import GROUND_TRUTH
from semmap.types import Frame, LabelSet


class FirstFrame:
    """A dataset's first frame, read only when something asks for it (a ROS bag pays a pass over its index)."""

    def __init__(self, dataset: Dataset):
        self._dataset, self._read, self._frame = dataset, False, None

    @property
    def frame(self) -> Frame | None:
        if not self._read:
            self._frame, self._read = next(iter(self._dataset), None), True
        return self._frame


def label_set_for(config: RunConfig, dataset: Dataset, segmenter: Segmenter | None) -> LabelSet | None:
    """The classes of the maps: the segmenter's, the dataset's, a generic set when label images come without
    names, or none (geometry and colour only)."""
    if segmenter is not None:
        return segmenter.label_set
    if dataset.label_set is not None:
        return dataset.label_set
    s = config.semantics.source
    if s == SemanticSource.LABELS or (s == SemanticSource.AUTO and config.input.labels is not None):
        return LabelSet.generic(FALLBACK_CLASSES)
    return None


def dynamic_classes(config: RunConfig, label_set: LabelSet | None) -> tuple[int, ...]:
    """Ids of the dynamic classes (``mapping.dynamic``) in the maps' label set: a name the set lacks is refused
    in one line, except a default one (a label set without people has none to leave out); none without classes."""
    named = [n for n in config.mapping.dynamic if n not in DEFAULT_DYNAMIC]
    if named and (label_set is None or config.semantics.source == SemanticSource.NONE):
        raise ConfigError(f"--dynamic {','.join(named)}: the run has no classes (--semantics "
                          f"{config.semantics.source.value}), so no point is of a dynamic class; map with a "
                          f"segmenter or label images, or leave --dynamic out")
    if label_set is None:
        return ()
    ids = []
    for name in config.mapping.dynamic:
        if name in label_set.names:
            ids.append(label_set.names.index(name))
        elif name not in DEFAULT_DYNAMIC:
            raise ConfigError(f"--dynamic: class {name!r} is not in the run's label set "
                              f"({', '.join(label_set.names[:12])}{', ...' if len(label_set) > 12 else ''})")
    if len(label_set) > 1 and set(range(1, len(label_set))) <= set(ids):
        raise ConfigError(f"--dynamic names every class of the run's label set ({len(label_set) - 1} classes): no "
                          f"point could occupy a voxel and the map would stay empty; name only the classes that move")
    return tuple(ids)


#: How report.md, report.json and the run's summary name semantics taken from the frames' own label images.
GROUND_TRUTH_LABELS = "ground-truth labels from the dataset (not a segmenter)"
#: ... and a run without classes.
NO_SEMANTICS = "none (geometry and colour only)"


def semantics_source(config: RunConfig, segmenter: Segmenter | None, label_set: LabelSet | None,
                     dataset_labels: LabelSet | None = None) -> str:
    """Where the map's classes came from, in words for the report: the segmenter by name, the dataset's own label
    images (a simulated sequence's are its ground truth: a map fused from them is not a segmenter's; the dataset
    names them in ``dataset_labels``), or none."""
    if segmenter is not None:
        from semmap.perception.registry import SegmenterName

        if segmenter.name == SegmenterName.ORACLE:
            return f"segmenter {segmenter.name} (simulated from the ground-truth labels, with CNN-like errors)"
        if segmenter.name == SegmenterName.PRECOMPUTED and config.semantics.weights is not None:
            return f"segmenter {segmenter.name} (predictions in {config.semantics.weights})"
        if config.semantics.model:
            folded = f", classes folded by {config.semantics.class_map}" if config.semantics.class_map else ""
            return f"segmenter {segmenter.name}:{config.semantics.model}{folded}"
        return f"segmenter {segmenter.name}"
    if label_set is None or config.semantics.source == SemanticSource.NONE:
        return NO_SEMANTICS
    if config.input.labels is not None:
        return f"label images from {config.input.labels} (not a segmenter)"
    if dataset_labels is None:  # --semantics labels on a dataset without any
        return f"{NO_SEMANTICS}: the dataset has no label images"
    return GROUND_TRUTH_LABELS


def check_labels_exist(config: RunConfig, dataset: Dataset, first: FirstFrame, segmenter: Segmenter | None) -> None:
    """``--semantics labels`` on a dataset without label images (no label folder, no label set, none on the first
    frame) is refused in one line before mapping, not mapped without semantics."""
    if segmenter is not None or config.semantics.source != SemanticSource.LABELS or config.input.labels is not None:
        return
    frame = first.frame
    if dataset.label_set is None and frame is not None and frame.labels is None and frame.semantics is None:
        raise ConfigError(f"{config.input.dataset}: --semantics labels, but the dataset has no label images (frame "
                          f"{frame.name} has none); name a folder of them with --labels, or choose another "
                          "--semantics")


def prepare_segmenter(segmenter: Segmenter | None, first: FirstFrame) -> float:
    """Let a segmenter with a start-up cost pay it on the dataset's first frame; returns the seconds."""
    if not isinstance(segmenter, Preparable) or first.frame is None:
        return 0.0
    return segmenter.prepare(first.frame)


def warm_tracker(config: RunConfig, first: FirstFrame) -> float:
    """Online, run a throwaway tracker of the same kind on the first frame twice, so that its kernels are compiled
    (or loaded) before the first frame's latency is counted; returns the seconds."""
    if config.mode != LoopMode.ONLINE or config.poses.source == GROUND_TRUTH:
        return 0.0
    from semmap.poses.track import METHODS, make_tracker

    source = config.poses.source
    if source not in METHODS or first.frame is None:  # (object-constrained trackers share the instance
        return 0.0  # source's state: not warmed)
    t0 = time.perf_counter()
    warm = make_tracker(source)
    for _ in range(2):
        warm.track(first.frame)
    return time.perf_counter() - t0


def pose_source_for(config: RunConfig, dataset: Dataset, *, instances: InstanceSource | None = None,
                    track_progress: Progress | None = None) -> FramePoses:
    """Where each frame's pose comes from: ground truth, a trajectory file, or a tracker run over the sequence
    first (its final, loop-closed trajectory is then used for mapping; online, frame by frame in the loop)."""
    source = config.poses.source
    if source == GROUND_TRUTH:
        return FramePoses(GROUND_TRUTH)
    from semmap.object_slam import make_pose_tracker
    from semmap.poses.base import estimate_trajectory
    from semmap.poses.track import METHODS, OBJECT_METHODS

    if source in METHODS or source in OBJECT_METHODS:
        t0 = time.perf_counter()
        tracker = make_pose_tracker(source, instances=instances)
        if config.mode == LoopMode.ONLINE:  # tracked in the frame loop, frame by frame
            return FramePoses(source, tracker=tracker)
        progress = track_progress or (lambda it, n: it)
        trajectory = estimate_trajectory(tracker, dataset, total=len(dataset),  # Ctrl-C stops between frames
                                         progress=lambda it, n: checked(progress(it, n), "tracking"))
        tracking_s = time.perf_counter() - t0
        if len(trajectory) == 0:
            raise ConfigError(f"{config.input.dataset}: the {source} tracker lost every frame")
        stats = getattr(tracker, "stats", None)
        return FramePoses(source, by_name=dict(zip(trajectory.names, trajectory.poses, strict=True)),
                          tracking_s=tracking_s, tracked=len(trajectory),
                          edge_stats=dataclasses.asdict(stats) if dataclasses.is_dataclass(stats) else None)
    from semmap.poses.file import TrajectoryPoses

    path = Path(source)
    if not path.is_file():
        raise ConfigError(f"--poses must be {GROUND_TRUTH}, a tracker ({', '.join(METHODS + OBJECT_METHODS)}) or a "
                          f"trajectory file; {path} {path_kind(path)}")
    return FramePoses(str(path), lookup=TrajectoryPoses.from_file(path, max_time_diff=config.poses.max_time_diff))



def pose_source_to_resume(config: RunConfig, dataset: Dataset) -> FramePoses:
    """The pose source a resumed run restores from its checkpoint: a tracker's poses come from the checkpoint
    (no second tracking pass), ground truth and trajectory files are opened again."""
    from semmap.poses.track import METHODS, OBJECT_METHODS

    source = config.poses.source
    if source in METHODS or source in OBJECT_METHODS:
        return FramePoses(source)
    return pose_source_for(config, dataset)


def simulated_realism(dataset: object, path: object = None) -> str | None:
    """The realism preset simulated frames were rendered with: a simulated dataset's (its ``realism``), or the one a
    ``semmap simulate`` folder's scene.json records (``clean`` for folders written before presets existed);
    None for recorded data."""
    if isinstance(getattr(dataset, "realism", None), str):
        return dataset.realism
    import json
    from pathlib import Path

    from semmap.errors import SemmapError
    from semmap.files.safe import read_text_limited
    from semmap.sim.realism import DEFAULT_REALISM

    root = getattr(dataset, "root", None) or path
    scene_json = Path(root) / "scene.json" if root is not None else None
    if scene_json is None or not scene_json.is_file():
        return None
    try:
        info = json.loads(read_text_limited(scene_json, what="scene description"))
    except (OSError, ValueError, SemmapError):
        return None
    if not isinstance(info, dict) or "generator_version" not in info:
        return None
    return str(info.get("realism", DEFAULT_REALISM))
