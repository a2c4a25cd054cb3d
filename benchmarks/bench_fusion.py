"""Label fusion and maps on simulated scenes with exact ground truth: every rule x map x segmenter preset, +- CRF.

For each scene (different kinds and seeds) the frames are rendered once; each oracle preset (``cnn-like``,
``voxel-grid-paper``, ``independent``, and ``perfect`` = the ground-truth labels, the upper bound) segments them
once; then one pass over the frames feeds the same observations (the path ``semmap run`` takes: back-projection,
then ``map.integrate``) to every map: the semantic OctoMap (topk), and the voxel grid and the point map with each
fusion rule.  Every map is scored against the scene's ground-truth voxels (``eval.semantic``), then refined by the
3D dense CRF and scored again.  Label set: the simulator's 30 classes padded to 40 (the issue's 40-class setting).
Each row also scores the map at the pixels of every 10th frame against the network at the same pixels
(``eval.pixels``: ``pixel_miou_map``, ``pixel_miou_network``, their ``gain``), beside the fusion ceiling of the
preset's labels over all frames (``ceiling_voxel_accuracy``, ``unreachable_share``); ``octomap-first`` is the
OctoMap fusing only the first point of each voxel and frame (OctoMap's discretized insert) against the default's
mean of all its points.

A timing section integrates 640x480 frames into the OctoMap and into the voxel grid with K = 40 (bayes) in the
same loop, frame by frame (contention hits both alike), and reports the memory per voxel with 40 and 150 classes.

Two sweeps replace the presets when asked (each row keeps the fields above):

- ``--temperatures 0.5,1,2``: the ``cnn-like`` oracle and the shipped network (``--network``, default the demo's)
  segment once; their class sets are tempered (``perception.calibration.apply_temperature``, as ``semmap run
  --temperature`` does) and fused by the OctoMap and the voxel grid with every rule; each row has ``temperature``
  and the segmenter's calibration at that temperature (``ece``: expected calibration error of the top class over
  15 bins, ``mean_confidence``, ``pixel_accuracy_2d``).
- ``--crf-sweep``: the same two segmenters fused by each map's own rule (T = 1), then the 3D CRF with each setting of
  ``CRF_SETTINGS`` (the default, SemanticFusion's, and one parameter changed at a time) on the same fused map;
  each row has ``crf_setting`` and its ``gain`` at the same pixels (``crf_gain``: map after the CRF minus before).

Frames are rendered with the ``--realism`` preset (default ``kinect``: structured-light depth, a real colour camera,
hand-held motion; ``clean`` for today's exact frames); every row names it.

    python benchmarks/bench_fusion.py [--quick] [--scenes N] [--scene-set held-out|validation]
                                      [--temperatures T,...] [--crf-sweep]
                                      [--realism clean|kinect|hard] [--resolution M]

Prints a table and, last, one JSON line:
{"bench": "fusion", "realism", "results": [{"scene", "realism", "preset", "map", "fusion", "crf", "miou", "accuracy",
"bytes_per_voxel", "ms_per_frame", "pixel_miou_network", "pixel_miou_map", "gain", "pixel_coverage",
"ceiling_voxel_accuracy", "unreachable_share", "temperature"}...], "upper_bound": {"<scene>": miou}, "timing": {...}}
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import dataclass, replace

import numpy as np

from semmap.datasets.simulated import SimulatedDataset
from semmap.eval.pixels import EVERY, PixelScores, fusion_ceiling, map_labels_at
from semmap.eval.semantic import evaluate_cloud_3d
from semmap.fusion.crf import SEMANTICFUSION, CrfParams, refine_map
from semmap.fusion.rules import FusionParams, FusionRule
from semmap.geometry import DEFAULT_MAX_DEPTH, DEFAULT_MIN_DEPTH, backproject_world, pixel_normals
from semmap.labels import INDOOR_LABELS
from semmap.maps.point_map import SemanticPointMap
from semmap.maps.registry import MapKind, compile_kernels
from semmap.maps.semantic_octomap import CellEvidence, SemanticOctoMap
from semmap.maps.voxel_grid import SemanticVoxelGrid
from semmap.perception.calibration import apply_temperature
from semmap.perception.oracle import OracleSegmenter
from semmap.perception.registry import demo_network, trained_network_segmenter
from semmap.perception.schedule import Scheduler, SegmentationSchedule
from semmap.sim.ground_truth import gt_voxels
from semmap.sim.realism import REALISMS, realism
from semmap.sim.scene import generate_scene
from semmap.sim.trajectory import make_trajectory
from semmap.types import CameraIntrinsics, LabelSet, Observation, TopKProbs, distinct_colors

#: The maps' voxel size (m); ``--resolution`` sets it for a run (issue 33 asks for 5 cm and 2 cm).
RESOLUTION = 0.05
SMALL = CameraIntrinsics(320, 240, 262.5, 262.5, 159.5, 119.5)
PRESETS = ("cnn-like", "voxel-grid-paper", "independent")
#: Rules the perfect labels are fused with (every rule agrees on perfect labels up to geometry).
PERFECT_RULES = (FusionRule.TOPK, FusionRule.BAYES, FusionRule.VOTE)
#: (kind, seed, size) of the scenes.
SCENES = (("office", 0, "medium"), ("kitchen", 1, "medium"), ("bedroom", 2, "medium"))
QUICK_SCENES = (("office", 0, "small"), ("kitchen", 1, "small"), ("bedroom", 2, "small"))
#: Scenes to choose settings on (``--scene-set validation``): the seeds of the networks' validation scenes
#: (scripts/make_training_data.py, 300-307, two per kind; never trained on), at the quick size, so that a setting
#: is picked there and checked once on the held-out scenes above.
VALIDATION_SCENES = tuple((("office", "kitchen", "living_room", "bedroom")[i % 4], 300 + i, "small") for i in range(8))
#: the simulator's preset by default (issue 34)
DEFAULT_REALISM = "kinect"


def padded_labels(n: int) -> LabelSet:
    """The simulator's classes followed by unused ``spare_i`` classes up to ``n``."""
    extra = n - len(INDOOR_LABELS)
    colors = np.vstack([INDOOR_LABELS.colors, distinct_colors(n)[len(INDOOR_LABELS):]])
    return LabelSet(INDOOR_LABELS.names + tuple(f"spare_{i}" for i in range(extra)), colors)


@dataclass
class Frames:
    """One scene's rendered frames, back-projected once."""

    name: str
    scene: object
    frames: list
    obs: list  # Observation without semantics, per frame
    pixels: list  # flat pixel index of each point, per frame

    def true_labels(self, i: int) -> np.ndarray:
        """The true class of each point of frame ``i``."""
        return np.take(self.frames[i].labels.reshape(-1), self.pixels[i])


def render(kind: str, seed: int, size: str, n: int, stride: int, intrinsics: CameraIntrinsics,
           preset: str = DEFAULT_REALISM) -> Frames:
    """Every ``stride``-th of ``n * stride`` frames of a loop through one scene, with the ``preset`` realism."""
    scene = generate_scene(seed, kind, size)
    poses = make_trajectory(scene, "loop", n * stride, seed=seed, motion=realism(preset).motion)[::stride]
    ds = SimulatedDataset(scene, poses, seed=seed, intrinsics=intrinsics, name=f"{kind}-{size}-{seed}",
                          realism=preset)
    keyframe = Scheduler(SegmentationSchedule(keyframes=True))
    frames, obs, pixels = [], [], []
    for f in ds:
        pts, pix = backproject_world(f.depth, f.intrinsics, f.T_world_cam, min_depth=DEFAULT_MIN_DEPTH,
                                     max_depth=DEFAULT_MAX_DEPTH)
        key = keyframe.due(f.T_world_cam)
        normals = pixel_normals(f.depth, f.intrinsics, f.T_world_cam, pix) if key else None
        obs.append(Observation(pts, f.T_world_cam[:3, 3].copy(), np.take(f.rgb.reshape(-1, 3), pix, axis=0),
                               normals=normals, frame_index=f.index, keyframe=key))
        frames.append(f)
        pixels.append(pix)
    return Frames(ds.name, scene, frames, obs, pixels)


class PerfectLabels:
    """The true labels with confidence 0.9 (the upper bound), as a segmenter."""

    def __init__(self, num_classes: int) -> None:
        self.num_classes = num_classes

    def segment(self, frame) -> TopKProbs:
        return TopKProbs.from_hard_labels(frame.labels, 0.9, self.num_classes)


def semantics(frames: Frames, preset: str, label_set: LabelSet, seed: int) -> list[TopKProbs]:
    """Per-point class sets of every frame from the preset (``perfect``: the true labels, confidence 0.9)."""
    return segmented(frames, PerfectLabels(len(label_set)) if preset == "perfect"
                     else OracleSegmenter(label_set, preset=preset, seed=seed))


def segmented(frames: Frames, segmenter) -> list[TopKProbs]:
    """Per-point class sets of every frame as ``segmenter`` (an oracle or a network) gives them."""
    out = []
    for f, pix in zip(frames.frames, frames.pixels, strict=True):
        sem = segmenter.segment(f).reshape_flat()
        out.append(TopKProbs(np.take(sem.labels, pix, axis=0), np.take(sem.probs, pix, axis=0)))
    return out


def class_prior(others: list[Frames], num_classes: int) -> np.ndarray:
    """Pixel frequencies of the true classes in the other scenes' frames (a training-set prior for bayes-prior)."""
    counts = np.zeros(num_classes)
    for fr in others:
        for f in fr.frames:
            counts += np.bincount(f.labels.ravel(), minlength=num_classes)[:num_classes]
    return counts


def build_maps(label_set: LabelSet, prior: np.ndarray, point_resolution: float, rules) -> list:
    maps = [SemanticOctoMap(RESOLUTION, label_set=label_set),
            SemanticOctoMap(RESOLUTION, label_set=label_set, cell_evidence=CellEvidence.FIRST)]
    for rule in rules:
        fusion = FusionParams(rule, prior=prior if rule == FusionRule.BAYES_PRIOR else None)
        maps.append(SemanticVoxelGrid(RESOLUTION, label_set=label_set, fusion=fusion))
        maps.append(SemanticPointMap(point_resolution, label_set=label_set, fusion=fusion))
    return maps


def fusion_of(m) -> str:
    return m.fusion.name


def map_name(m) -> str:
    """The map's kind; ``octomap-first`` for an OctoMap taking only each voxel's first point of a frame."""
    first = m.kind == MapKind.OCTOMAP and m.cell_evidence == CellEvidence.FIRST
    return "octomap-first" if first else m.kind.value


def pixel_scores(m, frames: Frames, sems: list[TopKProbs], num_classes: int) -> dict:
    """The map at the pixels of every EVERY-th frame against the preset's labels at the same pixels."""
    acc = PixelScores(num_classes)
    for i in range(0, len(frames.obs), EVERY):
        gt = frames.true_labels(i)
        keep = gt != 0
        acc.add(gt[keep], sems[i].labels[keep, 0], map_labels_at(m, frames.obs[i].points_world[keep]))
    s = acc.summary()
    return {"pixel_miou_network": s["pixel_miou_network"], "pixel_miou_map": s["pixel_miou_map"],
            "gain": s["pixel_gain"], "pixel_coverage": s["pixel_coverage"]}


def ceiling(frames: Frames, sems: list[TopKProbs]) -> dict:
    """The fusion ceiling of a preset's labels over every frame (``eval.pixels.fusion_ceiling``)."""
    gts = [frames.true_labels(i) for i in range(len(frames.obs))]
    keep = [g != 0 for g in gts]
    c = fusion_ceiling(np.concatenate([o.points_world[k] for o, k in zip(frames.obs, keep, strict=True)]),
                       np.concatenate([g[k] for g, k in zip(gts, keep, strict=True)]),
                       np.concatenate([s.labels[k, 0] for s, k in zip(sems, keep, strict=True)]), RESOLUTION)
    return {"ceiling_voxel_accuracy": c["ceiling_voxel_accuracy"], "unreachable_share": c["unreachable_share"]}


def bytes_per_voxel(m) -> float:
    n = m.num_leaves if m.kind == MapKind.OCTOMAP else m.grid.num_voxels
    return round(m.memory_bytes / max(n, 1), 1)


def calibration(frames: Frames, sems: list[TopKProbs], bins: int = 15) -> dict:
    """How well the top class's probability matches how often it is right (labelled points of every frame):
    expected calibration error over ``bins`` equal-width bins, mean confidence, pixel accuracy."""
    conf, ok = [], []
    for i, s in enumerate(sems):
        gt = frames.true_labels(i)
        keep = gt != 0
        conf.append(s.probs[keep, 0].astype(np.float64))
        ok.append(s.labels[keep, 0] == gt[keep])
    c, right = np.concatenate(conf), np.concatenate(ok)
    which = np.clip((c * bins).astype(int), 0, bins - 1)
    n = np.bincount(which, minlength=bins)
    gap = np.abs(np.bincount(which, right, bins) - np.bincount(which, c, bins))
    return {"ece": round(float(gap.sum() / max(n.sum(), 1)), 4), "mean_confidence": round(float(c.mean()), 4),
            "pixel_accuracy_2d": round(float(right.mean()), 4)}


def run_preset(frames: Frames, sems: list[TopKProbs], maps: list, gt, label_set: LabelSet, crf: bool,
               viewpoint: np.ndarray) -> list[dict]:
    """Integrate every frame into every map (timed per map), score, CRF, score again."""
    ms = np.zeros(len(maps))
    for obs, sem in zip(frames.obs, sems, strict=True):
        o = Observation(obs.points_world, obs.origin, obs.colors, sem, normals=obs.normals,
                        frame_index=obs.frame_index, keyframe=obs.keyframe)
        for i, m in enumerate(maps):
            t = time.perf_counter()
            m.integrate(o)
            ms[i] += (time.perf_counter() - t) * 1e3
    rows = []
    top = ceiling(frames, sems)
    for i, m in enumerate(maps):
        base = {"map": map_name(m), "fusion": fusion_of(m), "bytes_per_voxel": bytes_per_voxel(m),
                "ms_per_frame": round(ms[i] / len(frames.obs), 2)}
        c = m.cloud()
        s = evaluate_cloud_3d(c.centers, c.labels, *gt, label_set, RESOLUTION)
        rows.append({**base, "crf": False, "miou": s["miou_3d"], "accuracy": s["voxel_accuracy_3d"],
                     **pixel_scores(m, frames, sems, len(label_set)), **top})
        if crf:
            r = refine_map(m, CrfParams(), viewpoint=viewpoint)
            c = m.cloud()
            s = evaluate_cloud_3d(c.centers, c.labels, *gt, label_set, RESOLUTION)
            rows.append({**base, "crf": True, "miou": s["miou_3d"], "accuracy": s["voxel_accuracy_3d"],
                         "crf_ms": round(r.ms, 1), **pixel_scores(m, frames, sems, len(label_set)), **top})
    return rows


def timing(n: int, seed: int = 0) -> dict:
    """ms per 640x480 frame: OctoMap (topk) against the voxel grid with K = 40 bayes, interleaved per frame;
    memory per voxel of the grid with 40 and 150 classes in float32 and float16."""
    scene = generate_scene(seed, "office", "medium")
    poses = make_trajectory(scene, "loop", n * 6, seed=seed)[::6]
    ds = SimulatedDataset(scene, poses, seed=seed)
    labels40 = padded_labels(40)
    oracle = OracleSegmenter(labels40, preset="cnn-like", seed=seed)
    octo = SemanticOctoMap(RESOLUTION, label_set=labels40)
    grids = {(k, dt): SemanticVoxelGrid(RESOLUTION, label_set=padded_labels(k), fusion=FusionParams(FusionRule.BAYES),
                                        dtype=dt) for k in (40, 150) for dt in ("float32", "float16")}
    t_octo = t_grid = 0.0
    points = 0
    for f in ds:
        pts, pix = backproject_world(f.depth, f.intrinsics, f.T_world_cam)
        sem = oracle.segment(f).reshape_flat()
        obs = Observation(pts, f.T_world_cam[:3, 3].copy(), np.take(f.rgb.reshape(-1, 3), pix, axis=0),
                          TopKProbs(np.take(sem.labels, pix, axis=0), np.take(sem.probs, pix, axis=0)))
        points += len(pts)
        t = time.perf_counter()
        octo.integrate(obs)
        t_octo += time.perf_counter() - t
        t = time.perf_counter()
        grids[40, "float32"].integrate(obs)
        t_grid += time.perf_counter() - t
        for key, g in grids.items():
            if key != (40, "float32"):
                g.integrate(obs)
    return {"frames": n, "width": 640, "height": 480, "points_per_frame": round(points / n),
            "octomap_ms": round(1e3 * t_octo / n, 2), "voxelgrid_bayes_k40_ms": round(1e3 * t_grid / n, 2),
            "ratio": round(t_grid / t_octo, 3), "octomap_bytes_per_voxel": bytes_per_voxel(octo),
            "bytes_per_voxel": {f"k{k}_{dt}": bytes_per_voxel(g) for (k, dt), g in grids.items()},
            "state_bytes_per_voxel": {f"k{k}_{dt}": k * (2 if dt == "float16" else 4) for (k, dt) in grids}}


def table(results: list[dict], upper: dict[str, float]) -> str:
    lines = [f"{'scene':28s} {'preset':17s} {'map':13s} {'fusion':11s} {'mIoU':>6s} {'+CRF':>6s} {'acc':>6s} "
             f"{'B/vox':>7s} {'ms/fr':>7s} {'px net':>6s} {'px map':>6s} {'gain':>6s} {'ceil':>6s}"]
    by = {(r["scene"], r["preset"], r["map"], r["fusion"], r["crf"]): r for r in results}
    for (scene, preset, kind, fusion, crf), r in by.items():
        if crf:
            continue
        after = by.get((scene, preset, kind, fusion, True))
        lines.append(f"{scene:28s} {preset:17s} {kind:13s} {fusion:11s} {r['miou']:6.3f} "
                     f"{after['miou'] if after else float('nan'):6.3f} {r['accuracy']:6.3f} "
                     f"{r['bytes_per_voxel']:7.1f} {r['ms_per_frame']:7.2f} {r['pixel_miou_network']:6.3f} "
                     f"{r['pixel_miou_map']:6.3f} {r['gain']:+6.3f} {r['ceiling_voxel_accuracy']:6.3f}")
    lines += [f"upper bound (perfect labels) {s}: {v:.3f}" for s, v in upper.items()]
    return "\n".join(lines)


# ------------------------------------------------------------------------------------------------- sweeps
#: The CRF settings of ``--crf-sweep``: the default, SemanticFusion's, and one parameter of the default changed
#: (``appearance_weight=4``: the default before the sweep of docs/EXPERIMENTS.md); ``per-pixel``: the default
#: kernels with a log-odds grid's unaries as summed per pixel (``refine_map(per_view=False)``, before issue 33's
#: per-view scale).
CRF_SETTINGS: dict[str, CrfParams] = {
    "default": CrfParams(), "semanticfusion": SEMANTICFUSION, "per-pixel": CrfParams(),
    **{f"{key}={value:g}": replace(CrfParams(), **{key: value}) for key, value in (
        ("appearance_weight", 0.0), ("appearance_weight", 4.0), ("smoothness_weight", 0.0),
        ("smoothness_weight", 3.0), ("appearance_position_std", 0.05), ("appearance_position_std", 0.3),
        ("appearance_color_std", 10.0), ("appearance_color_std", 40.0), ("smoothness_position_std", 0.15),
        ("smoothness_normal_std", 0.1), ("smoothness_normal_std", 0.6), ("iterations", 10))},
}


def sweep_segmenters(label_set: LabelSet, seed: int, network: str | None) -> list[tuple[str, object]]:
    """(name, segmenter): the ``cnn-like`` oracle and the shipped network ``network`` (None: none)."""
    out = [("cnn-like", OracleSegmenter(label_set, preset="cnn-like", seed=seed))]
    if network is not None:
        out.append((network, trained_network_segmenter(network, k=3)))
    return out


def temperature_sweep(fr: Frames, segmenters, temperatures: list[float], label_set: LabelSet, prior, gt,
                      viewpoint: np.ndarray) -> list[dict]:
    """Each segmenter's class sets tempered at each temperature, fused by the OctoMap (its own rule) and the voxel
    grid with every rule; the segmenter's calibration at that temperature beside each row."""
    rows = []
    for name, segmenter in segmenters:
        base = segmented(fr, segmenter)
        for t in temperatures:  # (the network's own classes: the "others" mass spreads over the simulator's 30)
            sems = base if t == 1 else [apply_temperature(s, t, num_classes=len(INDOOR_LABELS)) for s in base]
            maps = [SemanticOctoMap(RESOLUTION, label_set=label_set)]
            maps += [SemanticVoxelGrid(RESOLUTION, label_set=label_set, fusion=FusionParams(
                rule, prior=prior if rule == FusionRule.BAYES_PRIOR else None)) for rule in FusionRule]
            cal = calibration(fr, sems)
            for r in run_preset(fr, sems, maps, gt, label_set, crf=False, viewpoint=viewpoint):
                rows.append({**r, "scene": fr.name, "preset": name, "temperature": t, **cal})
    return rows


def crf_sweep(fr: Frames, segmenters, label_set: LabelSet, prior, gt, viewpoint: np.ndarray,
              point_resolution: float, settings: dict[str, CrfParams]) -> list[dict]:
    """Each segmenter fused by every map with its own rule, then each CRF setting on the same fused map (restored
    from its state before each); the pixel gain of the CRF beside the fusion's."""
    rows = []
    for name, segmenter in segmenters:
        sems = segmented(fr, segmenter)
        maps = [SemanticOctoMap(RESOLUTION, label_set=label_set),
                SemanticVoxelGrid(RESOLUTION, label_set=label_set, fusion=FusionParams(FusionRule.BAYES)),
                SemanticPointMap(point_resolution, label_set=label_set,
                                 fusion=FusionParams(FusionRule.BAYES_PRIOR, prior=prior))]
        for m, before in zip(maps, run_preset(fr, sems, maps, gt, label_set, crf=False, viewpoint=viewpoint),
                             strict=True):
            fused = {k: np.copy(v) for k, v in m.state().items()}
            rows.append({**before, "scene": fr.name, "preset": name, "temperature": 1.0, "crf_setting": "none",
                         "crf_gain": 0.0})
            for setting, params in settings.items():
                m.restore({k: np.copy(v) for k, v in fused.items()})
                r = refine_map(m, params, viewpoint=viewpoint, per_view=setting != "per-pixel")
                c = m.cloud()
                s = evaluate_cloud_3d(c.centers, c.labels, *gt, label_set, RESOLUTION)
                px = pixel_scores(m, fr, sems, len(label_set))
                rows.append({**before, "scene": fr.name, "preset": name, "temperature": 1.0, "crf": True,
                             "crf_setting": setting, "miou": s["miou_3d"], "accuracy": s["voxel_accuracy_3d"],
                             "crf_ms": round(r.ms, 1), **px,
                             "crf_gain": round(px["pixel_miou_map"] - before["pixel_miou_map"], 4)})
            print(f"{fr.name} {name} {map_name(m)}: CRF sweep done", flush=True)
    return rows


def sweep_table(rows: list[dict], key: str) -> str:
    """One line per row of a sweep: the swept value, the map's scores and the segmenter's calibration."""
    lines = [f"{'scene':22s} {'segmenter':9s} {'map':10s} {'fusion':11s} {key:>28s} {'mIoU':>6s} {'px net':>6s} "
             f"{'px map':>6s} {'gain':>7s} {'crf+':>7s} {'ece':>6s}"]
    for r in rows:
        lines.append(f"{r['scene']:22s} {r['preset']:9s} {r['map']:10s} {r['fusion']:11s} {r[key]!s:>28s} "
                     f"{r['miou']:6.3f} {r['pixel_miou_network']:6.3f} {r['pixel_miou_map']:6.3f} {r['gain']:+7.3f} "
                     f"{r.get('crf_gain', 0.0):+7.3f} {r.get('ece', float('nan')):6.3f}")
    return "\n".join(lines)


def run_sweeps(args, rendered: list[Frames], label_set: LabelSet, point_resolution: float) -> list[dict]:
    """The temperature and CRF sweeps asked for, over every rendered scene."""
    temperatures = [float(t) for t in args.temperatures.split(",")] if args.temperatures else []
    rows: list[dict] = []
    for i, fr in enumerate(rendered):
        gt = gt_voxels(fr.scene, RESOLUTION)
        gt = (gt.keys, gt.class_ids)
        others = rendered[:i] + rendered[i + 1:]
        prior = class_prior(others, len(label_set)) if others else None
        viewpoint = np.mean([o.origin for o in fr.obs], axis=0)
        segmenters = sweep_segmenters(label_set, args.first_scene + i, args.network)
        if temperatures:
            found = temperature_sweep(fr, segmenters, temperatures, label_set, prior, gt, viewpoint)
            print(sweep_table(found, "temperature"), flush=True)
            rows += found
        if args.crf_sweep:
            settings = ({name: CRF_SETTINGS[name] for name in args.crf_settings.split(",")} if args.crf_settings
                        else CRF_SETTINGS)
            found = crf_sweep(fr, segmenters, label_set, prior, gt, viewpoint, point_resolution, settings)
            print(sweep_table(found, "crf_setting"), flush=True)
            rows += found
    return rows


def main() -> None:
    global RESOLUTION  # every function reads the run's voxel size from here (--resolution)
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="small scenes, fewer frames, 3 cm points (< 10 min)")
    parser.add_argument("--scenes", type=int, default=None, help="only the first N scenes")
    parser.add_argument("--frames", type=int, default=None, help="frames per scene (default 24 quick, 60 full)")
    parser.add_argument("--temperatures", default=None, help="sweep these temperatures (e.g. 0.5,1,2,4) instead of "
                        "the presets")
    parser.add_argument("--crf-sweep", action="store_true", help="sweep the CRF settings instead of the presets")
    parser.add_argument("--crf-settings", default=None, help="only these CRF_SETTINGS names (comma-separated)")
    parser.add_argument("--first-scene", type=int, default=0, help="start at this scene (0-based)")
    parser.add_argument("--scene-set", default="held-out", choices=("held-out", "validation"), help="the held-out "
                        "scenes (seeds 0-2) or the validation scenes to choose settings on (seeds 300-307, quick size)")
    parser.add_argument("--realism", default=DEFAULT_REALISM, choices=REALISMS, help="the simulator's preset")
    parser.add_argument("--resolution", type=float, default=RESOLUTION, help="voxel size of the maps, the ground "
                        "truth and the ceiling (m; default 0.05)")
    parser.add_argument("--network", default=demo_network(), help="shipped network of the sweeps (default: the "
                        "demo's)")
    args = parser.parse_args()
    if not 0.005 <= args.resolution <= 0.5:
        parser.error(f"--resolution must be from 0.005 to 0.5 m, got {args.resolution:g}")
    RESOLUTION = args.resolution
    n, stride = (24, 12) if args.quick else (60, 5)
    if args.frames:
        n, stride = args.frames, max(1, n * stride // args.frames)
    scenes = VALIDATION_SCENES if args.scene_set == "validation" else QUICK_SCENES if args.quick else SCENES
    scenes = scenes[args.first_scene:][: args.scenes]
    point_resolution = 0.03 if args.quick else 0.02  # coarser than the map's 1 cm default: 45 CRFs over its points
    t_start = time.perf_counter()
    compile_kernels(list(MapKind))
    label_set = padded_labels(40)
    rendered = [render(kind, seed, size, n, stride, SMALL, args.realism) for kind, seed, size in scenes]
    print(f"rendered {len(scenes)} scenes x {n} frames ({SMALL.width}x{SMALL.height}) in "
          f"{time.perf_counter() - t_start:.0f} s", flush=True)
    if args.temperatures or args.crf_sweep:
        rows = [{**r, "realism": args.realism} for r in run_sweeps(args, rendered, label_set, point_resolution)]
        print(f"total {time.perf_counter() - t_start:.0f} s")
        print(json.dumps({"bench": "fusion-sweeps", "realism": args.realism, "quick": args.quick, "frames": n,
                          "resolution": RESOLUTION, "scene_set": args.scene_set,
                          "point_resolution": point_resolution, "classes": len(label_set), "network": args.network,
                          "results": rows}))
        return
    results: list[dict] = []
    upper: dict[str, float] = {}
    for i, fr in enumerate(rendered):
        gt = gt_voxels(fr.scene, RESOLUTION)
        gt = (gt.keys, gt.class_ids)
        others = rendered[:i] + rendered[i + 1:]  # (a single scene: no prior, bayes-prior is bayes)
        prior = class_prior(others, len(label_set)) if others else None
        viewpoint = np.mean([o.origin for o in fr.obs], axis=0)
        for preset in ("perfect", *PRESETS):
            sems = semantics(fr, preset, label_set, seed=i)
            perfect = preset == "perfect"
            rules = PERFECT_RULES if perfect else tuple(FusionRule)
            maps = build_maps(label_set, prior, point_resolution, rules)
            rows = run_preset(fr, sems, maps, gt, label_set, crf=not perfect, viewpoint=viewpoint)
            for r in rows:
                r.update(scene=fr.name, preset=preset, temperature=1.0, realism=args.realism)
            if perfect:
                upper[fr.name] = max(r["miou"] for r in rows)
            results += rows
            print(f"{fr.name} {preset}: done ({time.perf_counter() - t_start:.0f} s)", flush=True)
    timed = timing(6 if args.quick else 30)
    print(table(results, upper))
    print(f"timing at 640x480: OctoMap {timed['octomap_ms']} ms/frame, voxel grid K=40 bayes "
          f"{timed['voxelgrid_bayes_k40_ms']} ms/frame (ratio {timed['ratio']}); bytes per voxel "
          f"{timed['bytes_per_voxel']} (machine shared: ratios, not absolute times)")
    print(f"total {time.perf_counter() - t_start:.0f} s")
    order = ("scene", "realism", "preset", "map", "fusion", "crf", "miou", "accuracy", "bytes_per_voxel",
             "ms_per_frame", "pixel_miou_network", "pixel_miou_map", "gain", "pixel_coverage", "ceiling_voxel_accuracy",
             "unreachable_share", "temperature")
    print(json.dumps({"bench": "fusion", "realism": args.realism, "quick": args.quick, "frames": n,
                      "resolution": RESOLUTION, "scene_set": args.scene_set,
                      "point_resolution": point_resolution, "classes": len(label_set),
                      "results": [{k: r[k] for k in order} for r in results], "upper_bound": upper,
                      "timing": timed}))


if __name__ == "__main__":
    main()
