"""Object-map metrics as the object-oriented SLAM paper reports them (its Tables 3-6), against simulator truth.

- Object count error per class and over all classes (eq. 24 without the x100): ``|D - GT| / GT``, with D the
  map's real objects of a class and GT the ground-truth objects of that class the camera saw well enough to map
  (at least ``min_pixels`` pixels in at least ``min_sightings`` frames and ``min_keyframes`` keyframes, the map's
  own rule: an object the camera never showed cannot be counted). Over all classes the error is
  ``sum |D_c - GT_c| / sum GT_c``, so a missing chair and an extra cup do not cancel; ``count_error_eq24`` is
  the paper's ``|D - GT| / GT`` of the totals.
- Centroid error: each map object is paired with the ground-truth instance most of its detections' pixels
  belonged to (one map object per instance, the one with most pixels); distance of the centroids, against the
  object's surface centroid in ``objects.json`` and against the centroid of its observed surface (the ground-truth
  masks of the same keyframes back-projected with the true poses and voxel-filtered alike), which is what a map
  can reconstruct without seeing the underside or the back of an object against a wall.
- Identity switches (CLEAR-MOT): per frame each ground-truth instance is represented by the detection covering
  most of its pixels; a switch is counted when its track id differs from the one it had last.
- Point reduction (Table 6): points of the dense map against points of the object clouds.
"""

from __future__ import annotations

import itertools
from collections import defaultdict
from dataclasses import dataclass, field

import numpy as np

from semmap.maps.objects import pack_cells
from semmap.types import LabelSet


def detection_truth(ids: np.ndarray, gt_instances: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """For detections 1..n of an id image: the ground-truth instance covering most of each mask (0: none) and
    how many pixels it covers there."""
    sel = (ids > 0) & (gt_instances > 0)
    if not sel.any() or n == 0:
        return np.zeros(n, np.int64), np.zeros(n, np.int64)
    det = ids[sel].astype(np.int64)
    gt = gt_instances[sel].astype(np.int64)
    pairs, counts = np.unique(det << 32 | gt, return_counts=True)
    d, g = pairs >> 32, pairs & 0xFFFFFFFF
    order = np.lexsort((-counts, d))
    first = np.ones(len(order), bool)
    first[1:] = d[order][1:] != d[order][:-1]
    best = order[first]
    truth = np.zeros(n, np.int64)
    cover = np.zeros(n, np.int64)
    truth[d[best] - 1] = g[best]
    cover[d[best] - 1] = counts[best]
    return truth, cover


@dataclass
class IdentitySwitches:
    """CLEAR-MOT identity switches of a tracker over a sequence (feed it every tracked frame)."""

    switches: int = 0
    matched: int = 0
    _last: dict[int, int] = field(default_factory=dict)

    def add(self, track_ids: np.ndarray, truth: np.ndarray, cover: np.ndarray) -> None:
        """One frame: per detection its track id, ground-truth instance and covered pixels."""
        best: dict[int, tuple[int, int]] = {}
        for tid, g, c in zip(track_ids.tolist(), truth.tolist(), cover.tolist(), strict=True):
            if g > 0 and tid > 0 and c > best.get(g, (0, -1))[1]:
                best[g] = (tid, c)
        for g, (tid, _) in best.items():
            self.matched += 1
            if g in self._last and self._last[g] != tid:
                self.switches += 1
            self._last[g] = tid


def count_errors(map_classes: list[int], gt_classes: list[int], label_set: LabelSet) -> dict:
    """Eq. 24 per class and over all classes for the map's real objects' classes and the visible truth's."""
    d = np.bincount(np.asarray(map_classes, np.int64), minlength=len(label_set))
    g = np.bincount(np.asarray(gt_classes, np.int64), minlength=len(label_set))
    per_class = {label_set.names[c]: {"detected": int(d[c]), "ground_truth": int(g[c]),
                                      "error": round(abs(int(d[c]) - int(g[c])) / g[c], 4) if g[c] else None}
                 for c in np.flatnonzero((d > 0) | (g > 0))}
    total_gt = max(int(g.sum()), 1)
    return {"count_error": round(float(np.abs(d - g).sum()) / total_gt, 4),
            "count_error_eq24": round(abs(int(d.sum()) - int(g.sum())) / total_gt, 4),
            "objects_detected": int(d.sum()), "objects_ground_truth": int(g.sum()), "per_class": per_class}


@dataclass
class ObjectTruth:
    """Ground truth collected along a run: which instance each map object's detections covered, and each
    instance's visibility and observed surface."""

    min_pixels: int = 150
    votes: dict[int, dict[int, int]] = field(default_factory=lambda: defaultdict(lambda: defaultdict(int)))
    seen: dict[int, int] = field(default_factory=lambda: defaultdict(int))  # frames with min_pixels
    in_keyframes: dict[int, int] = field(default_factory=lambda: defaultdict(int))  # keyframes with min_pixels
    observed: dict[int, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)  # cell keys, points

    def add_detections(self, object_ids: np.ndarray, truth: np.ndarray, cover: np.ndarray) -> None:
        for oid, g, c in zip(object_ids.tolist(), truth.tolist(), cover.tolist(), strict=True):
            if oid > 0 and g > 0:
                self.votes[oid][g] += c

    def add_frame(self, gt_instances: np.ndarray) -> None:
        """Any tracked frame's ground-truth instance image (which instances it shows well enough)."""
        counts = np.bincount(gt_instances.ravel().astype(np.int64))
        for g in np.flatnonzero(counts >= self.min_pixels):
            if g > 0:
                self.seen[int(g)] += 1

    def add_keyframe(self, gt_instances: np.ndarray, world_points: np.ndarray, point_instances: np.ndarray,
                     voxel: float) -> None:
        """A keyframe's ground-truth instance image and its instance pixels back-projected with the true pose
        (call :meth:`add_frame` for it too)."""
        counts = np.bincount(gt_instances.ravel().astype(np.int64))
        for g in np.flatnonzero(counts >= self.min_pixels):
            if g > 0:
                self.in_keyframes[int(g)] += 1
        if len(world_points) == 0:
            return
        keys = pack_cells(np.floor(world_points / voxel).astype(np.int64))
        inst = np.asarray(point_instances, np.int64)
        order = np.lexsort((keys, inst))
        inst, keys, pts = inst[order], keys[order], world_points[order]
        first = np.ones(len(order), bool)
        first[1:] = (inst[1:] != inst[:-1]) | (keys[1:] != keys[:-1])
        inst, keys, pts = inst[first], keys[first], pts[first]
        bounds = np.flatnonzero(np.r_[True, inst[1:] != inst[:-1], True])
        for a, b in itertools.pairwise(bounds):
            g = int(inst[a])
            old_keys, old_pts = self.observed.get(g, (keys[:0], pts[:0]))
            new = ~np.isin(keys[a:b], old_keys, assume_unique=True)
            self.observed[g] = (np.concatenate([old_keys, keys[a:b][new]]), np.concatenate([old_pts, pts[a:b][new]]))

    def visible(self, min_sightings: int, min_keyframes: int = 1) -> list[int]:
        """Instances shown with ``min_pixels`` in ``min_sightings`` frames, ``min_keyframes`` of them keyframes."""
        return [g for g, n in self.seen.items() if n >= min_sightings and self.in_keyframes[g] >= min_keyframes]

    def pairs(self, object_ids: list[int]) -> dict[int, int]:
        """Map object id -> ground-truth instance: each object's majority instance, one object per instance."""
        best: dict[int, tuple[int, int]] = {}
        for oid in object_ids:
            v = self.votes.get(oid)
            if not v:
                continue
            g, c = max(v.items(), key=lambda kv: kv[1])
            if c > best.get(g, (0, -1))[1]:
                best[g] = (oid, c)
        return {oid: g for g, (oid, _) in best.items()}

    def observed_centroid(self, g: int) -> np.ndarray | None:
        found = self.observed.get(g)
        return None if found is None or len(found[1]) == 0 else found[1].mean(axis=0)


#: A map object covers a ground-truth instance when that instance holds at least this share of the object's
#: detection pixels that lie on any instance (summed over its keyframes): a quarter keeps a chair leg's stray
#: pixels on the floor's edge from counting, and a table that swallowed a chair's seat does count.
COVER_SHARE = 0.25


@dataclass
class SegmentationTruth:
    """Over- and under-segmentation of an object map against ground-truth instances: per map object, how many of
    its keyframe detections' pixels fell on each ground-truth instance (feed every keyframe)."""

    cover_share: float = COVER_SHARE
    pixels: dict[int, dict[int, int]] = field(default_factory=lambda: defaultdict(lambda: defaultdict(int)))

    def add_keyframe(self, object_ids: np.ndarray, detection_ids: np.ndarray, gt_instances: np.ndarray) -> None:
        """One keyframe: the object id each detection joined (``ObjectMap.integrate``'s answer), the detections'
        id image (0 = none, k + 1 on detection k) and the ground-truth instance image."""
        sel = (detection_ids > 0) & (gt_instances > 0)
        if not sel.any():
            return
        det = detection_ids[sel].astype(np.int64) - 1
        gt = gt_instances[sel].astype(np.int64)
        pairs, counts = np.unique(det << 32 | gt, return_counts=True)
        for key, c in zip(pairs.tolist(), counts.tolist(), strict=True):
            k, g = key >> 32, key & 0xFFFFFFFF
            if k < len(object_ids) and object_ids[k] > 0:
                self.pixels[int(object_ids[k])][g] += c

    def scores(self, real_ids: list[int], resolve) -> dict:
        """Over- and under-segmentation of the real objects ``real_ids`` (ids recorded earlier are mapped through
        ``resolve``, the map's merges): ground-truth instances covered by two or more objects (over), objects
        covering two or more instances (under), with the instances each covers."""
        merged: dict[int, dict[int, int]] = defaultdict(lambda: defaultdict(int))
        for oid, hist in self.pixels.items():
            for g, c in hist.items():
                merged[resolve(oid)][g] += c
        covers: dict[int, list[int]] = {}
        for oid in real_ids:
            hist = merged.get(oid, {})
            total = sum(hist.values())
            covers[oid] = sorted(g for g, c in hist.items() if total and c >= self.cover_share * total)
        by_instance: dict[int, list[int]] = defaultdict(list)
        for oid, gs in covers.items():
            for g in gs:
                by_instance[g].append(oid)
        over = sorted(g for g, oids in by_instance.items() if len(oids) >= 2)
        under = sorted(oid for oid, gs in covers.items() if len(gs) >= 2)
        return {"objects": len(real_ids), "instances_covered": len(by_instance),
                "over_segmented": len(over), "under_segmented": len(under),
                "over_rate": round(len(over) / max(len(by_instance), 1), 4),
                "under_rate": round(len(under) / max(len(real_ids), 1), 4),
                "over_instances": over, "under_objects": under,
                "objects_per_instance": {g: oids for g, oids in sorted(by_instance.items()) if len(oids) >= 2}}
