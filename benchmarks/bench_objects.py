"""The object map against simulator truth, as the object-oriented SLAM paper's Tables 3-7, and its cost.

Per simulated scene and oracle instance error level (``maskrcnn-like``, ``noisy``; see
``semmap.perception.instances.oracle``), with ground-truth poses: instances every frame, DeepSORT every frame,
the object map on keyframes (10 cm / 10 degrees, as ``semmap run``). Measured (``semmap.eval.objects``):

- object count error over all object classes (eq. 24 without the x100, |D_c - GT_c| summed over classes, against
  the objects seen with at least 150 pixels in at least 3 frames, one a keyframe) and per class;
- mean centroid error against each object's observed surface (the true masks back-projected with the true poses)
  and against ``objects.json``'s whole-surface centroid (which includes faces the camera never sees);
- tracker identity switches; point reduction (Table 6: the keyframes' dense points against the objects' points);
- ms per frame of tracking, ms per keyframe of the object map, and the object stage per keyframe in all; the peer is
  Open3D's statistical outlier removal and voxel filter (the paper's PCL filters) on the same detection clouds.

Then the camera poses (Table 7): ATE of a tracker and of the same tracker with object-constrained keyframe poses
(``--poses X-objects``) on simulated sequences where the tracker drifts. One JSON line per scene, level and pose
run, a table, and the summary JSON last:
``{"bench": "objects", "results": [{"scene", "instances", "count_error", "centroid_error_m", "id_switches",
"ms_per_frame", "ate_without_m", "ate_with_m"}, ...]}``.

Frames are rendered with the ``--realism`` preset (default ``kinect``; ``clean`` for today's exact frames); every
row names it.

    python benchmarks/bench_objects.py [--quick] [--levels maskrcnn-like,noisy] [--no-poses] [--scenes a,b]
                                       [--frames N] [--realism clean|kinect|hard] [--pose-runs a,b]

With ``--segmentation`` instead: over- and under-segmentation of the object map with ``--instances components``
on the scenes from seed 500 (``--realisms kinect,hard``, ``--semantics oracle|fcn``, ground-truth poses, 320x240).
A ground-truth instance is over-segmented when two or more of the map's objects cover it, a map object is
under-segmented when two or more instances each hold a quarter of its keyframe detection pixels. Every variant
(``cut``: components and map as they were, ``join-frames``, ``join-map``, ``joined``: both) runs on the same frames
and segmentation. One JSON line per scene, preset and variant, two tables, the summary JSON last.

    python benchmarks/bench_objects.py --segmentation [--realisms kinect,hard] [--semantics oracle,fcn]
                                       [--seg-scenes a,b] [--frames N]

Timings are wall-clock on whatever else the machine runs; compare the ratios.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np
import open3d as o3d

from semmap.datasets.simulated import SimulatedDataset
from semmap.eval.objects import IdentitySwitches, ObjectTruth, SegmentationTruth, count_errors, detection_truth
from semmap.eval.trajectory import evaluate_trajectory
from semmap.labels import INDOOR_LABELS
from semmap.maps.objects import ObjectMap, ObjectMapParams
from semmap.object_slam import make_pose_tracker
from semmap.perception.instances.oracle import OracleInstances
from semmap.perception.schedule import Scheduler, SegmentationSchedule
from semmap.perception.tracking import DeepSort
from semmap.sim.realism import REALISMS
from semmap.types import Trajectory

#: name -> (scene seed, kind, trajectory, frames)
SCENES = {"office-loop": (0, "office", "loop", 300), "kitchen-loop": (1, "kitchen", "loop", 300),
          "living-walk": (2, "living_room", "walk", 300), "bedroom-walk": (3, "bedroom", "walk", 300)}
QUICK_SCENES = {"office-loop": (0, "office", "loop", 150), "kitchen-loop": (1, "kitchen", "loop", 150)}
#: pose runs: name -> (scene seed, kind, trajectory, frames, tracker)
#: (the dense odometry has neither a map nor loop closure: on ``kinect`` it drifts 1.4-1.7 cm over the loops)
POSE_RUNS = {"sim-loop-features": (1, "office", "loop", 450, "slam-features"),
             "sim-walk-features": (3, "office", "walk", 600, "slam-features"),
             "sim-loop-noloop": (1, "office", "loop", 450, "slam-noloop"),
             "sim-loop-odometry": (1, "office", "loop", 450, "odometry"),
             "sim-loop2-odometry": (2, "office", "loop", 450, "odometry"),
             "sim-walk-odometry": (3, "office", "walk", 600, "odometry")}
QUICK_POSE_RUNS = {"sim-loop-features": (1, "office", "loop", 300, "slam-features")}
LEVELS = ("maskrcnn-like", "noisy")
#: the simulator's preset by default (issue 34)
DEFAULT_REALISM = "kinect"
#: visibility rule of the ground truth: pixels in a keyframe, keyframes
MIN_PIXELS, MIN_SIGHTINGS = 150, 3


def map_scene(name: str, seed: int, kind: str, trajectory: str, frames: int, level: str,
              realism: str = DEFAULT_REALISM, window: bool = False) -> dict:
    """One object-map run with ground-truth poses on frames of the ``realism`` preset; its metrics and timings
    (``window``: the object map's optional sightings from the frames between keyframes)."""
    ds = SimulatedDataset.default(scene_seed=seed, kind=kind, trajectory=trajectory, frames=frames, realism=realism)
    source = OracleInstances(ds.label_set, preset=level, seed=seed)
    tracker = DeepSort(num_classes=len(ds.label_set))
    omap = ObjectMap(ds.label_set, ObjectMapParams(window_sightings=window))
    keyframe = Scheduler(SegmentationSchedule(keyframes=True))
    switches, truth = IdentitySwitches(), ObjectTruth(min_pixels=MIN_PIXELS)
    gt_class: dict[int, int] = {}
    t_track = t_map = t_peer = 0.0
    keyframes = dense_points = 0
    for f in ds:
        found = source.detect(f)
        t0 = time.perf_counter()
        tracked = tracker.update(found, f, f.T_world_cam)
        t_track += time.perf_counter() - t0
        omap.count_track_frames(tracked.track_ids)
        g, cover = detection_truth(tracked.ids, f.instances, len(tracked))
        switches.add(tracked.track_ids, g, cover)
        truth.add_frame(f.instances)
        if not keyframe.due(f.T_world_cam):
            t0 = time.perf_counter()
            omap.note(tracked, f.depth, f.rgb, f.intrinsics, f.T_world_cam)  # what a keyframe's detector may miss
            t_map += time.perf_counter() - t0
            continue
        keyframes += 1
        dense_points += int(((f.depth > omap.params.min_depth) & (f.depth <= omap.params.max_depth)).sum())
        t0 = time.perf_counter()
        ids = omap.integrate(tracked, f.depth, f.rgb, f.intrinsics, f.T_world_cam, f.index)
        t_map += time.perf_counter() - t0
        t_peer += _peer_filters(tracked, f, omap)
        truth.add_detections(ids, g, cover)
        pts, inst = _true_surface(f, omap.params.pixel_stride, omap.params.min_depth, omap.params.max_depth)
        truth.add_keyframe(f.instances, pts, inst, omap.params.voxel)
        for gid in np.unique(inst):
            gt_class.setdefault(int(gid), int(np.bincount(f.labels[f.instances == gid]).argmax()))
    real = omap.real_objects()
    visible = [gid for gid in truth.visible(MIN_SIGHTINGS, omap.params.min_keyframes) if gid in gt_class]
    counts = count_errors([o.class_id for o in real], [gt_class[gid] for gid in visible], ds.label_set)
    scene_objects = {o.instance_id: o for o in ds.scene.objects}
    by_id = {o.id: o for o in real}
    pairs = truth.pairs(list(by_id))
    observed = [np.linalg.norm(by_id[o].centroid - truth.observed_centroid(gid)) for o, gid in pairs.items()
                if truth.observed_centroid(gid) is not None]
    whole = [np.linalg.norm(by_id[o].centroid - scene_objects[gid].centroid) for o, gid in pairs.items()
             if gid in scene_objects]
    object_points = sum(len(o) for o in real)
    ms_stage = 1e3 * (t_track + t_map) / max(keyframes, 1)
    return {"scene": name, "instances": level, "realism": realism, "frames": frames, "keyframes": keyframes,
            "count_error": counts["count_error"], "count_error_eq24": counts["count_error_eq24"],
            "objects": counts["objects_detected"], "objects_ground_truth": counts["objects_ground_truth"],
            "centroid_error_m": round(float(np.mean(observed)), 4) if observed else None,
            "centroid_median_m": round(float(np.median(observed)), 4) if observed else None,
            "centroid_error_whole_m": round(float(np.mean(whole)), 4) if whole else None,
            "id_switches": switches.switches, "detections_matched": switches.matched,
            "points_dense": dense_points, "points_objects": object_points,
            "point_reduction": round(1 - object_points / max(dense_points, 1), 4),
            "ms_per_frame": round(1e3 * (t_track + t_map) / frames, 2),
            "tracking_ms_per_frame": round(1e3 * t_track / frames, 2),
            "map_ms_per_keyframe": round(1e3 * t_map / max(keyframes, 1), 2),
            "stage_ms_per_keyframe": round(ms_stage, 2),
            "peer_filters_ms_per_keyframe": round(1e3 * t_peer / max(keyframes, 1), 2),
            "per_class": {c: v for c, v in counts["per_class"].items() if v["detected"] != v["ground_truth"]},
            "ate_without_m": None, "ate_with_m": None}


#: scenes of the segmentation measure (``--segmentation``): seeds from 500 on, never in any training set
SEGMENTATION_SCENES = {"office-500": (500, "office", "loop"), "kitchen-501": (501, "kitchen", "loop"),
                       "living-502": (502, "living_room", "walk"), "bedroom-503": (503, "bedroom", "walk"),
                       "office-504": (504, "office", "walk"), "kitchen-505": (505, "kitchen", "walk"),
                       "living-506": (506, "living_room", "loop"), "bedroom-507": (507, "bedroom", "loop")}
#: the segmentation measure's frames: 320x240 (half the simulator's 640x480), every third of a 30 Hz walk (more of
#: the room for the same rendering time), frames per scene
SEGMENTATION_SCALE, SEGMENTATION_STEP, SEGMENTATION_FRAMES = 0.5, 3, 100
#: what is compared on the same frames and semantics: name -> (components join parts an occluder cut apart,
#: the object map's part_share): today's cut components and map, each half of the change, and both
SEGMENTATION_VARIANTS = {"cut": (False, 2.0), "join-frames": (True, 2.0), "join-map": (False, 0.8),
                         "joined": (True, 0.8)}


def segmentation_scene(name: str, seed: int, kind: str, trajectory: str, frames: int, realism: str,
                       semantics: str, variants: tuple[str, ...] = tuple(SEGMENTATION_VARIANTS)) -> list[dict]:
    """Over- and under-segmentation of the object map with ``--instances components`` on one simulated scene
    (ground-truth poses, 320x240): the segmenter ``semantics`` (``oracle``: the true classes; ``fcn``: the shipped
    simulator-trained network) runs once per frame and every variant's instances, tracker and map use its
    output. One row per variant."""
    from semmap.perception.instances.components import ComponentInstances
    from semmap.perception.registry import make_segmenter

    scene = SimulatedDataset.default(scene_seed=seed, kind=kind, trajectory=trajectory,
                                     frames=frames * SEGMENTATION_STEP, realism=realism)
    ds = SimulatedDataset(scene.scene, scene.poses[::SEGMENTATION_STEP], seed=seed, realism=realism,
                          name=scene.name, intrinsics=scene.intrinsics.scaled(SEGMENTATION_SCALE))
    segmenter = make_segmenter(semantics, label_set=ds.label_set, oracle_preset="voxel-grid-paper", seed=seed,
                               threads=1)
    runs = {v: (ComponentInstances(ds.label_set, join=SEGMENTATION_VARIANTS[v][0]),
                DeepSort(num_classes=len(ds.label_set)),
                ObjectMap(ds.label_set, ObjectMapParams(part_share=SEGMENTATION_VARIANTS[v][1])),
                SegmentationTruth(), ObjectTruth(min_pixels=MIN_PIXELS // 4))
            for v in variants}
    gt_class: dict[int, int] = {}
    keyframe = Scheduler(SegmentationSchedule(keyframes=True))
    t_seg = 0.0
    t_inst = dict.fromkeys(variants, 0.0)
    keyframes = 0
    for f in ds:
        t0 = time.perf_counter()
        sem = segmenter.segment(f)
        t_seg += time.perf_counter() - t0
        is_key = keyframe.due(f.T_world_cam)
        keyframes += is_key
        for v, (source, tracker, omap, seg, truth) in runs.items():
            t0 = time.perf_counter()
            found = source.detect(f, sem)
            t_inst[v] += time.perf_counter() - t0
            tracked = tracker.update(found, f, f.T_world_cam)
            omap.count_track_frames(tracked.track_ids)
            truth.add_frame(f.instances)
            if is_key:
                ids = omap.integrate(tracked, f.depth, f.rgb, f.intrinsics, f.T_world_cam, f.index)
                seg.add_keyframe(ids, tracked.ids, f.instances)
                truth.add_keyframe(f.instances, np.zeros((0, 3)), np.zeros(0, np.int64), omap.params.voxel)
        if is_key:
            for gid in np.unique(f.instances[f.instances > 0]):
                gt_class.setdefault(int(gid), int(np.bincount(f.labels[f.instances == gid]).argmax()))
    rows = []
    for v, (_, _, omap, seg, truth) in runs.items():
        real = omap.real_objects()
        found = seg.scores([o.id for o in real], omap.resolve)
        visible = [g for g in truth.visible(MIN_SIGHTINGS, omap.params.min_keyframes) if g in gt_class]
        counts = count_errors([o.class_id for o in real], [gt_class[g] for g in visible], ds.label_set)
        names = ds.label_set.names
        rows.append({"scene": name, "realism": realism, "semantics": semantics, "variant": v,
                     "frames": frames, "keyframes": keyframes, "objects": len(real),
                     "objects_ground_truth": counts["objects_ground_truth"], "count_error": counts["count_error"],
                     **{k: found[k] for k in ("instances_covered", "over_segmented", "under_segmented",
                                              "over_rate", "under_rate")},
                     "over_classes": sorted(names[gt_class.get(g, 0)] for g in found["over_instances"]),
                     "under_classes": sorted(names[o.class_id] for o in real if o.id in found["under_objects"]),
                     "segmenter_ms_per_frame": round(1e3 * t_seg / frames, 1),
                     "instances_ms_per_frame": round(1e3 * t_inst[v] / frames, 2)})
    return rows


def _peer_filters(tracked, frame, omap: ObjectMap) -> float:
    """Seconds Open3D's statistical outlier removal (8 neighbours, k = 1) and 1 cm voxel filter take on the same
    back-projected detection clouds (the paper's PCL filters)."""
    s = omap.params.pixel_stride
    ids = tracked.ids[::s, ::s]
    d = frame.depth[::s, ::s]
    K = frame.intrinsics
    v, u = np.nonzero((ids > 0) & (d >= omap.params.min_depth) & (d <= omap.params.max_depth))
    z = d[v, u].astype(np.float64)
    pts = np.column_stack([(u * s - K.cx) / K.fx * z, (v * s - K.cy) / K.fy * z, z])
    det = ids[v, u]
    clouds = [o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts[det == k])) for k in np.unique(det)]
    t0 = time.perf_counter()
    for c in clouds:
        if len(c.points) > 9:
            kept, _ = c.remove_statistical_outlier(nb_neighbors=8, std_ratio=1.0)
            kept.voxel_down_sample(omap.params.voxel)
    return time.perf_counter() - t0


def _true_surface(frame, stride: int, min_depth: float, max_depth: float) -> tuple[np.ndarray, np.ndarray]:
    """World points and instance ids of the true instance masks (every ``stride``-th pixel), true pose."""
    inst = frame.instances[::stride, ::stride]
    d = frame.depth[::stride, ::stride]
    v, u = np.nonzero((inst > 0) & (d >= min_depth) & (d <= max_depth))
    z = d[v, u].astype(np.float64)
    K = frame.intrinsics
    pc = np.column_stack([(u * stride - K.cx) / K.fx * z, (v * stride - K.cy) / K.fy * z, z])
    T = frame.T_world_cam
    return pc @ T[:3, :3].T + T[:3, 3], inst[v, u].astype(np.int64)


def pose_run(name: str, seed: int, kind: str, trajectory: str, frames: int, tracker: str, level: str,
             realism: str = DEFAULT_REALISM) -> dict:
    """ATE of ``tracker`` and of ``tracker-objects`` on one simulated sequence of the ``realism`` preset."""
    seq = list(SimulatedDataset.default(scene_seed=seed, kind=kind, trajectory=trajectory, frames=frames,
                                        realism=realism))
    gt = Trajectory(np.array([f.timestamp for f in seq]), np.array([f.T_world_cam for f in seq]),
                    tuple(f.name for f in seq))
    row = {"scene": name, "instances": level, "realism": realism, "tracker": tracker}
    # one run: the object-constrained tracker drives the tracker itself, whose own trajectory is the "without"
    t = make_pose_tracker(tracker + "-objects", instances=OracleInstances(INDOOR_LABELS, preset=level, seed=seed))
    t0 = time.perf_counter()
    for f in seq:
        t.track(f)
    without = t.base.trajectory()
    t1 = time.perf_counter()
    est = t.trajectory()
    t2 = time.perf_counter()
    for key, traj in (("without", without), ("with", est)):
        found = evaluate_trajectory(gt, traj)
        row[f"ate_{key}_m"] = round(found["ate_rmse_m"], 5)
        row[f"frames_tracked_{key}"] = found["matched"]
    row["ms_per_frame_with"] = round(1e3 * (t2 - t0) / frames, 1)
    row["object_graph_s"] = round(t2 - t1, 2)
    row["object_edges"] = vars(t.stats)
    row["ate_ratio"] = round(row["ate_with_m"] / max(row["ate_without_m"], 1e-12), 3)
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="two scenes of 150 frames, one pose run of 300 frames")
    ap.add_argument("--levels", default=",".join(LEVELS), help="oracle instance error presets")
    ap.add_argument("--no-poses", action="store_true", help="skip the object-constrained pose runs")
    ap.add_argument("--realism", default=DEFAULT_REALISM, choices=REALISMS, help="the simulator's preset")
    ap.add_argument("--scenes", help=f"comma-separated subset of {', '.join(SCENES)}")
    ap.add_argument("--frames", type=int, help="frames per object scene (default 300, quick 150)")
    ap.add_argument("--window-sightings", action="store_true",
                    help="the object map also takes what a keyframe's detector missed from the frames before it")
    ap.add_argument("--pose-runs",
                    help=f"comma-separated subset of the pose runs {', '.join(POSE_RUNS)} (alone: no object scenes)")
    ap.add_argument("--segmentation", action="store_true",
                    help="instead: over- and under-segmentation with --instances components on the scenes from seed "
                         "500 (--semantics, --realisms, --seg-scenes, --frames)")
    ap.add_argument("--semantics", default="oracle", help="segmenters of --segmentation (oracle: the true classes; "
                                                            "fcn: the shipped simulator network), comma-separated")
    ap.add_argument("--realisms", default="kinect,hard", help="presets of --segmentation, comma-separated")
    ap.add_argument("--seg-scenes", help=f"comma-separated subset of {', '.join(SEGMENTATION_SCENES)}")
    args = ap.parse_args()
    if args.segmentation:
        _segmentation(ap, args)
        return
    levels = [s for s in args.levels.split(",") if s]
    scenes = _chosen_scenes(ap, args)
    rows = []
    for name, spec in scenes.items():
        for level in levels:
            row = map_scene(name, *spec, level, args.realism, args.window_sightings)
            print(json.dumps(row), flush=True)
            rows.append(row)
    pose_rows = []
    if not args.no_poses:
        for name, spec in _chosen_pose_runs(ap, args).items():
            row = pose_run(name, *spec, levels[0], args.realism)
            print(json.dumps(row), flush=True)
            pose_rows.append(row)
    _table(rows, pose_rows)
    keys = ("scene", "instances", "realism", "count_error", "centroid_error_m", "id_switches", "ms_per_frame",
            "ate_without_m", "ate_with_m")
    results = [{k: r.get(k) for k in keys} for r in rows]
    results += [{**{k: r.get(k) for k in keys}, "count_error": None, "centroid_error_m": None, "id_switches": None,
                 "ms_per_frame": r["ms_per_frame_with"], "tracker": r["tracker"]} for r in pose_rows]
    print(json.dumps({"bench": "objects", "results": results}))


def _segmentation(ap: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """The ``--segmentation`` measure: one JSON line per scene, preset, segmenter and variant, a table, a summary."""
    names = [s for s in (args.seg_scenes or ",".join(SEGMENTATION_SCENES)).split(",") if s]
    unknown = [s for s in names if s not in SEGMENTATION_SCENES]
    realisms = [s for s in args.realisms.split(",") if s]
    if unknown or not set(realisms) <= set(REALISMS):
        ap.error(f"unknown scene or preset {', '.join(unknown + sorted(set(realisms) - set(REALISMS)))}")
    frames = args.frames or SEGMENTATION_FRAMES
    rows = []
    for semantics in [s for s in args.semantics.split(",") if s]:
        for realism in realisms:
            for name in names:
                for row in segmentation_scene(name, *SEGMENTATION_SCENES[name], frames, realism, semantics):
                    print(json.dumps(row), flush=True)
                    rows.append(row)
    print("\n| scene | preset | semantics | variant | objects / truth | count error | over-segmented truth |"
          " under-segmented objects |")
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['scene']} | {r['realism']} | {r['semantics']} | {r['variant']} | {r['objects']} / "
              f"{r['objects_ground_truth']} | {100 * r['count_error']:.1f} % | {r['over_segmented']} / "
              f"{r['instances_covered']} {_classes(r['over_classes'])}| {r['under_segmented']} / {r['objects']} "
              f"{_classes(r['under_classes'])}|")
    summary = []
    for key in sorted({(r["realism"], r["semantics"], r["variant"]) for r in rows}):
        sel = [r for r in rows if (r["realism"], r["semantics"], r["variant"]) == key]
        over, covered = sum(r["over_segmented"] for r in sel), sum(r["instances_covered"] for r in sel)
        under, objects = sum(r["under_segmented"] for r in sel), sum(r["objects"] for r in sel)
        summary.append({"realism": key[0], "semantics": key[1], "variant": key[2], "scenes": len(sel),
                        "over_segmented": over, "instances_covered": covered,
                        "over_rate": round(over / max(covered, 1), 4), "under_segmented": under, "objects": objects,
                        "under_rate": round(under / max(objects, 1), 4),
                        "count_error": round(float(np.mean([r["count_error"] for r in sel])), 4)})
    print("\n| preset | semantics | variant | scenes | over-segmented truth | under-segmented objects |"
          " mean count error |")
    print("|---|---|---|---|---|---|---|")
    for s in summary:
        print(f"| {s['realism']} | {s['semantics']} | {s['variant']} | {s['scenes']} | {s['over_segmented']} / "
              f"{s['instances_covered']} ({100 * s['over_rate']:.1f} %) | {s['under_segmented']} / {s['objects']} "
              f"({100 * s['under_rate']:.1f} %) | {100 * s['count_error']:.1f} % |")
    print(json.dumps({"bench": "objects-segmentation", "frames": frames, "results": summary}))


def _classes(names: list[str]) -> str:
    """``(chair x2, desk)`` of a list of class names, or nothing."""
    if not names:
        return ""
    counts = {n: names.count(n) for n in sorted(set(names))}
    return "(" + ", ".join(n if c == 1 else f"{n} x{c}" for n, c in counts.items()) + ") "


def _chosen_scenes(ap: argparse.ArgumentParser, args: argparse.Namespace) -> dict:
    """The object scenes ``--quick``, ``--scenes`` and ``--frames`` ask for: name -> (seed, kind, path, frames)."""
    if getattr(args, "pose_runs", None) and not args.scenes:
        return {}  # --pose-runs alone: the pose runs only
    scenes = dict(QUICK_SCENES if args.quick else SCENES)
    if args.scenes:
        unknown = [s for s in args.scenes.split(",") if s not in SCENES]
        if unknown:
            ap.error(f"unknown scene {', '.join(unknown)}; known: {', '.join(SCENES)}")
        scenes = {s: scenes.get(s, SCENES[s]) for s in args.scenes.split(",")}
    if args.frames:
        if args.frames < 2:
            ap.error("--frames must be at least 2")
        scenes = {name: (*spec[:3], args.frames) for name, spec in scenes.items()}
    return scenes


def _chosen_pose_runs(ap: argparse.ArgumentParser, args: argparse.Namespace) -> dict:
    """The pose runs ``--quick`` and ``--pose-runs`` ask for: name -> (seed, kind, path, frames, tracker)."""
    if not args.pose_runs:
        return QUICK_POSE_RUNS if args.quick else POSE_RUNS
    names = [s for s in args.pose_runs.split(",") if s]
    unknown = [s for s in names if s not in POSE_RUNS]
    if unknown:
        ap.error(f"unknown pose run {', '.join(unknown)}; known: {', '.join(POSE_RUNS)}")
    return {s: POSE_RUNS[s] for s in names}


def _table(rows: list[dict], pose_rows: list[dict]) -> None:
    if rows:
        _scene_table(rows)
    if pose_rows:
        _pose_table(pose_rows)
    print()


def _scene_table(rows: list[dict]) -> None:
    print("\n| scene | instances | realism | objects / truth | count error | centroid error cm (whole object) |"
          " id switches | point reduction | tracking ms/frame | map ms/keyframe | Open3D filters ms/keyframe |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['scene']} | {r['instances']} | {r['realism']} | {r['objects']} / {r['objects_ground_truth']} | "
              f"{100 * r['count_error']:.1f} % | {100 * (r['centroid_error_m'] or 0):.2f} "
              f"({100 * (r['centroid_error_whole_m'] or 0):.1f}) | {r['id_switches']} | "
              f"{100 * r['point_reduction']:.1f} % | {r['tracking_ms_per_frame']:.1f} | "
              f"{r['map_ms_per_keyframe']:.1f} | {r['peer_filters_ms_per_keyframe']:.1f} |")


def _pose_table(pose_rows: list[dict]) -> None:
    print("\n| sequence | tracker | frames tracked | ATE cm | with objects ATE cm | ratio | object edges (agreeing) |")
    print("|---|---|---|---|---|---|---|")
    for r in pose_rows:
        e = r["object_edges"]
        print(f"| {r['scene']} | {r['tracker']} | {r['frames_tracked_without']} | {100 * r['ate_without_m']:.2f} | "
              f"{100 * r['ate_with_m']:.2f} | {r['ate_ratio']:.3f} | {e['edges']} ({e['agreeing_edges']}) |")


if __name__ == "__main__":
    main()
