"""Why visible objects are missing from the object map of ``benchmarks/bench_objects.py``, and where their depth
went.

Runs one object scene as the benchmark does (ground-truth poses, oracle instances, DeepSORT every frame, the object
map on keyframes) and gives every true object the benchmark counts as visible (150 px in 3 frames, 2 keyframes) one
fate: ``found`` (a real map object is paired with it), ``found-wrong-class``, ``never-detected-in-keyframe`` (no
detection's mask is mostly it in any keyframe), ``dropped`` (detected, but too few points with depth),
``one-keyframe`` (mapped from fewer than ``min_keyframes`` keyframes, not real), ``glued`` (its detections joined
real objects that belong to another true object). Per missed object: keyframes it shows 150 px in, keyframes
detected / mapped, the share of its keyframe pixels with sensor depth, and its median true depth. Then, per class
(default book), where the depth of its pixels in keyframes went: valid, below the sensor's minimum range, beyond its
maximum range, far dropout, beside a depth edge (shadow / edge dropout), dark material, other, by comparing the
sensor's depth with the exact depth of the same frames.

    PYTHONPATH=src:benchmarks python scripts/research/object_losses.py [--scene office-loop] [--frames 300]
        [--realism kinect] [--level maskrcnn-like] [--cls book] [--no-check] [--window]
"""

from __future__ import annotations

import argparse
import collections
import sys
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))
from bench_objects import MIN_PIXELS, MIN_SIGHTINGS, SCENES
from semmap.datasets.simulated import SimulatedDataset
from semmap.eval.objects import ObjectTruth, detection_truth
from semmap.maps.objects import ObjectMap, ObjectMapParams
from semmap.perception.instances.oracle import OracleInstances
from semmap.perception.schedule import Scheduler, SegmentationSchedule
from semmap.perception.tracking import DeepSort
from semmap.sim.realism import KINECT_DEPTH

EDGE_REL = 0.04  # a depth jump of this share of the depth within 2 px marks an edge


def depth_causes(frame, exact) -> np.ndarray:
    """Per pixel why the sensor's depth is missing (or "valid"), from the exact depth of the same view."""
    z, hole = exact.depth, frame.depth <= 0
    k = np.ones((5, 5), np.uint8)
    edge = (cv2.dilate(z, k) - cv2.erode(z, k)) > EDGE_REL * z
    luma = exact.rgb.astype(np.float32) @ np.array([0.299, 0.587, 0.114], np.float32)
    s = KINECT_DEPTH
    cause = np.full(z.shape, "valid", object)
    inside = hole & (z >= s.min_depth) & (z <= s.far_drop_from)
    cause[hole & (z < s.min_depth)] = f"below {s.min_depth} m"
    cause[hole & (z > s.far_drop_from)] = f"far dropout {s.far_drop_from}-{s.max_depth} m"
    cause[hole & (z > s.max_depth)] = f"beyond {s.max_depth} m"
    cause[inside & edge] = "beside a depth edge"
    cause[inside & ~edge & (luma < s.dark_luma)] = "dark material"
    cause[inside & ~edge & (luma >= s.dark_luma)] = "other"
    return cause


def run(args: argparse.Namespace) -> None:
    """Map the scene and print the fates and the depth causes."""
    seed, kind, path, _ = SCENES[args.scene]
    ds = SimulatedDataset.default(scene_seed=seed, kind=kind, trajectory=path, frames=args.frames,
                                  realism=args.realism)
    exact = SimulatedDataset(ds.scene, ds.poses, noise=False, seed=seed, realism="clean")
    source = OracleInstances(ds.label_set, preset=args.level, seed=seed)
    tracker = DeepSort(num_classes=len(ds.label_set))
    omap = ObjectMap(ds.label_set, ObjectMapParams(mask_check=not args.no_check, window_sightings=args.window))
    keyframe, truth = Scheduler(SegmentationSchedule(keyframes=True)), ObjectTruth(min_pixels=MIN_PIXELS)
    cid = ds.label_set.id_of(args.cls)
    stats: dict[int, collections.Counter] = collections.defaultdict(collections.Counter)
    causes: collections.Counter = collections.Counter()
    gt_class, joined = {}, collections.defaultdict(set)
    for f, fx in zip(ds, exact, strict=True):
        tracked = tracker.update(source.detect(f), f, f.T_world_cam)
        omap.count_track_frames(tracked.track_ids)
        g, cover = detection_truth(tracked.ids, f.instances, len(tracked))
        truth.add_frame(f.instances)
        if not keyframe.due(f.T_world_cam):
            omap.note(tracked, f.depth, f.rgb, f.intrinsics, f.T_world_cam)
            continue
        ids = omap.integrate(tracked, f.depth, f.rgb, f.intrinsics, f.T_world_cam, f.index)
        truth.add_detections(ids, g, cover)
        truth.add_keyframe(f.instances, np.zeros((0, 3)), np.zeros(0, np.int64), omap.params.voxel)
        cause = depth_causes(f, fx)
        counts = np.bincount(f.instances.ravel().astype(np.int64))
        for gid in (int(i) for i in np.flatnonzero(counts >= MIN_PIXELS) if i > 0):
            mask = f.instances == gid
            gt_class.setdefault(gid, int(np.bincount(f.labels[mask]).argmax()))
            s = stats[gid]
            s["keyframes"] += 1
            s["pixels"] += int(counts[gid])
            s["valid"] += int((cause[mask] == "valid").sum())
            s["depth_cm"] += round(100 * float(np.median(fx.depth[mask])))
            dets = np.flatnonzero(g == gid)
            s["detected"] += int(len(dets) > 0)
            s["mapped"] += int(any(ids[d] > 0 for d in dets))
            joined[gid].update(int(ids[d]) for d in dets if ids[d] > 0)
            if gt_class[gid] == cid:
                causes.update(cause[mask].tolist())
    report(args, omap, truth, ds.label_set.names, gt_class, stats, joined, causes)


def report(args, omap, truth, names, gt_class, stats, joined, causes) -> None:
    """Print each visible true object's fate (missed ones in detail) and the depth causes of ``args.cls``."""
    real = {o.id: o for o in omap.real_objects()}
    paired = {g: o for o, g in truth.pairs(list(real)).items()}
    visible = [g for g in truth.visible(MIN_SIGHTINGS, omap.params.min_keyframes) if g in gt_class]
    fates: collections.Counter = collections.Counter()
    print("missed: id class fate keyframes detected mapped valid-depth median-true-depth-m")
    for g in visible:
        s, objs = stats[g], {omap.resolve(o) for o in joined[g]}
        if g in paired:
            fate = "found" if real[paired[g]].class_id == gt_class[g] else "found-wrong-class"
        elif s["detected"] == 0:
            fate = "never-detected-in-keyframe"
        elif s["mapped"] == 0:
            fate = "dropped"
        elif not objs & set(real):
            fate = "one-keyframe"
        else:
            fate = "glued"
        fates[names[gt_class[g]], fate] += 1
        if fate != "found":
            print(f"  {g} {names[gt_class[g]]} {fate} {s['keyframes']} {s['detected']} {s['mapped']} "
                  f"{s['valid'] / max(s['pixels'], 1):.2f} {s['depth_cm'] / max(s['keyframes'], 1) / 100:.2f}")
    print(f"\n{args.scene} {args.frames} frames, {args.realism}, {args.level}: {len(real)} real objects, "
          f"{len(visible)} visible")
    for (c, fate), n in sorted(fates.items()):
        print(f"  {c:12s} {fate:28s} {n}")
    total = max(sum(causes.values()), 1)
    print(f"\n{args.cls} pixels in keyframes ({total}): " +
          ", ".join(f"{k} {100 * v / total:.1f} %" for k, v in causes.most_common()))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scene", default="office-loop", choices=list(SCENES))
    ap.add_argument("--frames", type=int, default=300)
    ap.add_argument("--realism", default="kinect")
    ap.add_argument("--level", default="maskrcnn-like")
    ap.add_argument("--cls", default="book", help="class whose lost depth is broken down")
    ap.add_argument("--no-check", action="store_true", help="the object map without its mask check")
    ap.add_argument("--window", action="store_true", help="the object map with sightings between keyframes")
    run(ap.parse_args())


if __name__ == "__main__":
    main()
