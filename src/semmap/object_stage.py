"""The object stage of a mapping run: instances every frame, DeepSORT every frame, the object map on keyframes.

Like ``pipeline.py`` it wires stages (perception's instance source and tracker, maps' object map) and writes their
outputs: ``objects.json``, ``objects.ply``, a top-down panel for ``preview.png`` and the ``objects`` entry of the
report. When frames carry ground-truth instance images (the simulator), it also scores the tracker (identity
switches) and the map (object count error per class, eq. 24) as :mod:`semmap.eval.objects` defines them.
"""

from __future__ import annotations

import time
from collections import defaultdict
from pathlib import Path

import numpy as np

from semmap.eval.objects import IdentitySwitches, ObjectTruth, count_errors, detection_truth
from semmap.io.objects import object_colors, write_objects_json, write_objects_ply
from semmap.maps.objects import ObjectMap, ObjectMapParams
from semmap.perception.instances.base import InstanceSource
from semmap.perception.tracking import DeepSort
from semmap.types import Frame, TopKProbs
from semmap.viz.objects import objects_top_down

#: Object records listed in report.md (all of them are in objects.json).
REPORT_ROWS = 60


class ObjectStage:
    """Per frame :meth:`step`; afterwards :meth:`write` the files and :meth:`report` the summary."""

    def __init__(self, source: InstanceSource, params: ObjectMapParams | None = None) -> None:
        self.source = source
        self.tracker = DeepSort(num_classes=len(source.label_set))
        self.map = ObjectMap(source.label_set, params)
        self.ms: dict[str, float] = defaultdict(float)
        self.frames = 0
        self.switches = IdentitySwitches()
        self.truth = ObjectTruth()
        self._gt_classes: dict[int, int] = {}
        self._scored = False
        self._keyframe_due = False

    def step(self, frame: Frame, T_world_cam: np.ndarray, semantics: TopKProbs | None, keyframe: bool) -> None:
        """Detect and track ``frame``'s instances; on keyframes add them to the object map. Sources built on a
        segmentation skip frames that were not segmented (a keyframe among them moves to the next segmented one)."""
        self._keyframe_due |= keyframe  # a keyframe the source could not see is taken at its next frame
        if semantics is None and self.source.needs_semantics:
            return
        t0 = time.perf_counter()
        found = self.source.detect(frame, semantics)
        t1 = time.perf_counter()
        tracked = self.tracker.update(found, frame, T_world_cam)
        t2 = time.perf_counter()
        self.ms["instances"] += (t1 - t0) * 1e3
        self.ms["tracking"] += (t2 - t1) * 1e3
        self.frames += 1
        self.map.count_track_frames(tracked.track_ids)
        truth = cover = None
        if frame.instances is not None and frame.instances.shape == tracked.ids.shape:
            truth, cover = detection_truth(tracked.ids, frame.instances, len(tracked))
            self.switches.add(tracked.track_ids, truth, cover)
            self.truth.add_frame(frame.instances)
            self._scored = True
        if self._keyframe_due:
            self._keyframe_due = False
            t3 = time.perf_counter()
            ids = self.map.integrate(tracked, frame.depth, frame.rgb, frame.intrinsics, T_world_cam, frame.index)
            self.ms["objects"] += (time.perf_counter() - t3) * 1e3
            if truth is not None:
                self._add_truth(frame, ids, truth, cover)
        else:  # between keyframes: what the next keyframe's detector may miss
            t3 = time.perf_counter()
            self.map.note(tracked, frame.depth, frame.rgb, frame.intrinsics, T_world_cam)
            self.ms["objects"] += (time.perf_counter() - t3) * 1e3

    def _add_truth(self, frame: Frame, ids: np.ndarray, truth: np.ndarray, cover: np.ndarray) -> None:
        self.truth.add_detections(ids, truth, cover)
        self.truth.add_keyframe(frame.instances, np.zeros((0, 3)), np.zeros(0, np.int64), self.map.params.voxel)
        if frame.labels is not None:
            inst = frame.instances.ravel().astype(np.int64)
            lab = frame.labels.ravel().astype(np.int64)
            for g in np.unique(inst[inst > 0]):
                if int(g) not in self._gt_classes:
                    self._gt_classes[int(g)] = int(np.bincount(lab[inst == g]).argmax())

    def write(self, out_dir: Path, up: np.ndarray) -> dict[str, int]:
        """``objects.json`` and ``objects.ply`` of the real objects; ``{file name: bytes}``."""
        real = self.map.real_objects()
        label_set = self.map.label_set
        return {"objects.json": write_objects_json(out_dir / "objects.json", real, label_set, up),
                "objects.ply": write_objects_ply(out_dir / "objects.ply", real)}

    def panel(self, up: np.ndarray, size: int) -> np.ndarray:
        """Top-down picture of the real objects with their ids (for ``preview.png``)."""
        real = self.map.real_objects()
        colors = object_colors(max([o.id for o in real], default=0))
        return objects_top_down(real, colors, self.map.label_set.names, up=up, size=size)

    def report(self, keyframes: int) -> dict:
        """Counts, timings and (with ground-truth instances) identity switches and count error."""
        m = self.map
        real = m.real_objects()
        names = m.label_set.names
        per_class: dict[str, int] = defaultdict(int)
        for o in real:
            per_class[names[o.class_id]] += 1
        out = {"instance_source": self.source.name, "objects": len(real), "candidates": len(m.objects) - len(real),
               # the rule of ObjectMap.real_objects, in the table's columns: frames_seen and sightings (keyframes)
               "kept_if_at_least": {"frames_seen": m.params.min_sightings, "sightings": m.params.min_keyframes},
               "per_class": dict(sorted(per_class.items(), key=lambda kv: -kv[1])),
               "points_in_masks": m.points_in, "points_after_outlier_removal": m.points_after_sor,
               "points_in_objects": sum(len(o) for o in real),
               "ms_per_frame": {"instances": round(self.ms["instances"] / max(self.frames, 1), 2),
                                "tracking": round(self.ms["tracking"] / max(self.frames, 1), 2)},
               "ms_per_keyframe": round(self.ms["objects"] / max(keyframes, 1), 2), "keyframes": m.keyframes,
               "table": [{"id": o.id, "class": names[o.class_id], "confidence": round(o.confidence, 3),
                          "centroid": [round(float(c), 3) for c in o.centroid], "points": len(o),
                          "sightings": o.sightings, "frames_seen": m.frames_seen(o)} for o in real[:REPORT_ROWS]]}
        if self._scored:
            visible = [g for g in self.truth.visible(m.params.min_sightings, m.params.min_keyframes)
                       if g in self._gt_classes]
            counts = count_errors([o.class_id for o in real], [self._gt_classes[g] for g in visible], m.label_set)
            out["id_switches"] = self.switches.switches
            out.update({k: counts[k] for k in ("count_error", "count_error_eq24", "objects_ground_truth")})
        return out
