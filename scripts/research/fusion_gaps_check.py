"""Why the default rules and the CRF fall short of issue 33's targets, on validation or held-out scenes.

Renders ``bench_fusion.py``'s quick scenes (``--scene-set held-out``: office/kitchen/bedroom seeds 0-2; or
``validation``: seeds 300-307, the networks' validation scenes at the quick size, never trained on), segments
each once with the shipped network (cached under ``--cache``), and at ``--resolution`` prints:

1. ``rules``: the OctoMap with ``topk`` at each Algorithm-1 confidence cap of ``--caps``, the voxel grid with
   ``bayes``, and both maps with each of ``--rules``: pixel MIoU gain over the network at the same pixels;
2. ``margins``: per map, the share of voxels whose unary gap (``-log`` of the second class minus of the first,
   as the CRF reads it) exceeds what the pairwise weights can overcome;
3. ``crf``: the CRF gain of the OctoMap (topk) and the grid (bayes) with each ``--crf`` entry (``default``,
   ``per-pixel``: the grid's unaries as summed per pixel, ``floor=E``, ``key=value;...``);
4. ``confidence``: the AUROC of the network's top-class confidence, and per voxel how often the plurality of
   its views, the most confident view (``max``) and the sum of log-probabilities are right (the voxel's true
   class: its pixels' plurality), overall and where the plurality is wrong.

With ``--points M`` the rules section fuses the point map (cells of M metres) with each of ``--rules`` instead.

    python scripts/research/fusion_gaps_check.py --scene-set validation [--resolution 0.02] [--only rules,crf]
        [--rules bayes,bayes-prior,vote,max] [--crf "default|per-pixel"] [--only confidence] [--points 0.03]
"""

from __future__ import annotations

import argparse
import importlib.util
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from semmap.fusion.crf import CrfParams, refine_map
from semmap.fusion.rules import FusionParams, FusionRule
from semmap.maps.point_map import SemanticPointMap
from semmap.maps.semantic_octomap import SemanticOctoMap
from semmap.maps.voxel_grid import SemanticVoxelGrid
from semmap.perception.registry import demo_network, trained_network_segmenter
from semmap.types import Observation, TopKProbs

K = 40


def _module(path: Path, name: str):
    """A script of this repository as a module, registered in ``sys.modules`` (a dataclass looks its module up)."""
    spec = importlib.util.spec_from_file_location(name, path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[name] = mod
    spec.loader.exec_module(mod)
    return mod


def bench_fusion():
    """benchmarks/bench_fusion.py as a module (its scenes, rendering and scoring)."""
    return _module(Path(__file__).resolve().parents[2] / "benchmarks" / "bench_fusion.py", "bench_fusion")


bench = bench_fusion()


def cached_sems(fr, cache: Path, realism: str) -> list[TopKProbs]:
    """The shipped network's per-point class sets of every frame (segmented once, then read from ``cache``)."""
    path = cache / f"{fr.name}-{realism}-{demo_network()}.npz"
    if path.exists():
        z = np.load(path)
        return [TopKProbs(z[f"l{i}"], z[f"p{i}"]) for i in range(len(fr.obs))]
    sems = bench.segmented(fr, trained_network_segmenter(demo_network(), k=3))
    cache.mkdir(parents=True, exist_ok=True)
    np.savez(path, **{f"l{i}": s.labels for i, s in enumerate(sems)}, **{f"p{i}": s.probs for i, s in enumerate(sems)})
    return sems


def build(fr, sems, maps: dict) -> dict:
    """Feed every frame to every map."""
    for obs, sem in zip(fr.obs, sems, strict=True):
        o = Observation(obs.points_world, obs.origin, obs.colors, sem, normals=obs.normals,
                        frame_index=obs.frame_index, keyframe=obs.keyframe)
        for m in maps.values():
            m.integrate(o)
    return maps


def loss_check():
    """scripts/research/fusion_loss_check.py as a module (its per-voxel selectors and AUROC)."""
    return _module(Path(__file__).resolve().parent / "fusion_loss_check.py", "fusion_loss_check")


def confidence_report(fr, sems: list[TopKProbs], resolution: float) -> dict[str, float]:
    """How much the network's top-class confidence says (AUROC right vs wrong over labelled pixels), and per voxel
    (every frame's points) how often the plurality of the views, the most confident view (``max``) and the sum of
    log-probabilities (``bayes``) are the voxel's true class (its pixels' plurality)."""
    lc = loss_check()
    keep = [fr.true_labels(i) != 0 for i in range(len(fr.obs))]
    gt = np.concatenate([fr.true_labels(i)[k] for i, k in enumerate(keep)])
    labels = np.concatenate([s.labels[k] for s, k in zip(sems, keep, strict=True)]).astype(np.int64)
    probs = np.concatenate([s.probs[k] for s, k in zip(sems, keep, strict=True)]).astype(np.float64)
    pts = np.concatenate([o.points_world[k] for o, k in zip(fr.obs, keep, strict=True)])
    _, inv = lc.voxel_index(pts, resolution)
    n = int(inv.max()) + 1
    true = lc.plurality(inv, gt, n)
    plural = lc.plurality(inv, labels[:, 0], n) == true
    top = lc.most_confident(inv, labels[:, 0], probs[:, 0], n) == true
    bayes = lc.summed(inv, labels, probs, n, log=True) == true
    sel = {"plurality": lc.plurality(inv, labels[:, 0], n), "max": lc.most_confident(inv, labels[:, 0], probs[:, 0], n),
           "bayes": lc.summed(inv, labels, probs, n, log=True)}
    mious = {f"voxel_miou_{k}": voxel_miou(true, v) for k, v in sel.items()}
    return {**mious, "auroc": lc.auroc(probs[:, 0], labels[:, 0] == gt), "plurality": float(plural.mean()),
            "max": float(top.mean()), "bayes": float(bayes.mean()),
            "max_where_plurality_wrong": float(top[~plural].mean()),
            "bayes_where_plurality_wrong": float(bayes[~plural].mean())}


def voxel_miou(true: np.ndarray, pred: np.ndarray) -> float:
    """Mean over the true classes of the voxels' IoU (each class weighs alike, as pixel MIoU weighs them)."""
    ious = [np.sum((true == c) & (pred == c)) / np.sum((true == c) | (pred == c)) for c in np.unique(true)]
    return float(np.mean(ious))


def margin_shares(m, limit: float) -> tuple[float, float]:
    """Share of voxels whose CRF unary gap (second minus first class, probabilities clipped at 1e-8) exceeds
    ``limit`` nats, and the median gap."""
    p = np.clip(m.class_probs(), 1e-8, 1.0)
    u = -np.log(np.sort(p, axis=1)[:, ::-1][:, :2])
    gap = u[:, 1] - u[:, 0]
    return float((gap > limit).mean()), float(np.median(gap))


def floored_refine(m, params: CrfParams, viewpoint: np.ndarray, floor: float) -> None:
    """The CRF reading every probability as at least ``floor`` (unary gaps at most ``-log floor``)."""
    from semmap.fusion import crf

    original = crf.dense_crf

    def floored(probs, positions, colors, normals, p):
        q = np.maximum(probs, floor)
        return original((q / q.sum(1, keepdims=True)).astype(np.float32), positions, colors, normals, p)

    crf.dense_crf = floored
    try:
        refine_map(m, params, viewpoint=viewpoint)
    finally:
        crf.dense_crf = original


def run_crf(m, name: str, params: CrfParams, viewpoint: np.ndarray) -> None:
    """One CRF variant: ``per-pixel`` (the grids' unaries as summed, before the per-view scale), ``floor=E``, or
    plain (``refine_map``'s default)."""
    if name.startswith("per-pixel"):
        refine_map(m, params, viewpoint=viewpoint, per_view=False)
    elif name.startswith("floor="):
        floored_refine(m, params, viewpoint, float(name.split("=")[1].split(";")[0]))
    else:
        refine_map(m, params, viewpoint=viewpoint)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene-set", default="validation", choices=("validation", "held-out"))
    ap.add_argument("--scenes", default=None, help="only these kinds (comma-separated)")
    ap.add_argument("--resolution", type=float, default=0.05)
    ap.add_argument("--realism", default="clean", choices=bench.REALISMS)
    ap.add_argument("--caps", default="0.999", help="topk confidence caps of the OctoMap (comma-separated)")
    ap.add_argument("--crf", default="default", help="CRF settings: default or key=value;key=value (| separated)")
    ap.add_argument("--only", default="rules,margins,crf")
    ap.add_argument("--rules", default="bayes", help="rules besides the defaults, in both maps (comma-separated; "
                    "bayes-prior's prior: the other scenes' class frequencies)")
    ap.add_argument("--cache", default="/tmp/fusion_gaps_cache")
    ap.add_argument("--points", type=float, default=None, help="instead of the OctoMap and the grid, the point map "
                    "at this cell size (m) with each of --rules")
    args = ap.parse_args()
    bench.RESOLUTION = args.resolution
    scenes = bench.VALIDATION_SCENES if args.scene_set == "validation" else bench.QUICK_SCENES
    if args.scenes:
        scenes = [s for s in scenes if s[0] in args.scenes.split(",")]
    only = set(args.only.split(","))
    label_set = bench.padded_labels(K)
    caps = [float(c) for c in args.caps.split(",")]
    crfs = {}
    for item in args.crf.split("|"):
        kv = [x for x in item.split(";") if x not in ("default", "per-pixel") and not x.startswith("floor=")]
        crfs[item] = replace(CrfParams(), **{k: float(v) for k, v in (x.split("=") for x in kv)})
    totals: dict[str, list[float]] = {}
    rendered = [bench.render(kind, seed, size, 24, 12, bench.SMALL, args.realism) for kind, seed, size in scenes]
    for i, fr in enumerate(rendered):
        sems = cached_sems(fr, Path(args.cache), args.realism)
        prior = bench.class_prior(rendered[:i] + rendered[i + 1:], K)
        maps = {f"octomap topk cap {c:g}": SemanticOctoMap(args.resolution, label_set=label_set,
                                                          fusion=FusionParams(FusionRule.TOPK, max_confidence=c))
                for c in caps}
        maps["grid bayes"] = SemanticVoxelGrid(args.resolution, label_set=label_set,
                                               fusion=FusionParams(FusionRule.BAYES))
        if args.points:  # the point map's rules only (its default bayes-prior first)
            maps = {}
        for rule in [FusionRule(r) for r in args.rules.split(",") if r]:
            fusion = FusionParams(rule, prior=prior if rule == FusionRule.BAYES_PRIOR else None)
            if args.points:
                maps[f"points {rule.value}"] = SemanticPointMap(args.points, label_set=label_set, fusion=fusion)
                continue
            maps[f"octomap {rule.value}"] = SemanticOctoMap(args.resolution, label_set=label_set, fusion=fusion)
            if rule != FusionRule.BAYES:
                maps[f"grid {rule.value}"] = SemanticVoxelGrid(args.resolution, label_set=label_set, fusion=fusion)
        if "confidence" in only:
            c = confidence_report(fr, sems, args.resolution)
            print(f"== {fr.name}: " + ", ".join(f"{k} {v:.3f}" for k, v in c.items()), flush=True)
            for k, v in c.items():
                totals.setdefault(f"confidence {k}", []).append(v)
            if only == {"confidence"}:
                continue
        build(fr, sems, maps)
        viewpoint = np.mean([o.origin for o in fr.obs], axis=0)
        print(f"== {fr.name} {args.realism} {args.resolution:g} m", flush=True)
        for name, m in maps.items():
            px = bench.pixel_scores(m, fr, sems, K)
            line = f"  {name:24s} net {px['pixel_miou_network']:.4f} map {px['pixel_miou_map']:.4f} " \
                   f"gain {100 * px['gain']:+5.1f}"
            totals.setdefault(name, []).append(100 * px["gain"])
            if "margins" in only:
                share, med = margin_shares(m, 12.0)
                line += f" | unary gap > 12 nats: {share:.2f}, median {med:.1f}"
            print(line, flush=True)
            if "crf" in only and name in ("grid bayes", f"octomap topk cap {caps[0]:g}"):
                fused = {k: np.copy(v) for k, v in m.state().items()}
                for cname, params in crfs.items():
                    if cname.startswith("per-pixel") and not name.startswith("grid"):
                        continue
                    m.restore({k: np.copy(v) for k, v in fused.items()})
                    run_crf(m, cname, params, viewpoint)
                    after = bench.pixel_scores(m, fr, sems, K)
                    g = 100 * (after["pixel_miou_map"] - px["pixel_miou_map"])
                    totals.setdefault(f"{name} CRF {cname}", []).append(g)
                    print(f"     CRF {cname:40s} {g:+5.1f}", flush=True)
                m.restore(fused)
    print("== mean over scenes")
    for name, v in totals.items():
        print(f"  {name:60s} {np.mean(v):+5.2f}  ({' / '.join(f'{x:+.1f}' for x in v)})")


if __name__ == "__main__":
    main()
