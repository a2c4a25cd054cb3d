"""Where a fused map loses pixels its network got right, and why ``max`` wins with the cnn-like oracle (issue 33).

Renders one of ``bench_fusion.py``'s quick scenes (24 frames, 320x240), segments it with the shipped network and
the ``cnn-like`` oracle, and prints three things:

1. ``maps``: the OctoMap (topk) and the voxel grid (bayes) at ``--resolution``, scored at the pixels of every 10th
   frame like ``eval.pixels``; the pixels the map loses (network right, map wrong) and wins, split by where they
   lie (within 2 px of a label boundary or a depth edge, in a voxel whose pixels have two true classes, in a voxel
   whose network plurality over all views is wrong), the gain if the map took the network's label on each such
   set (counterfactual), and each class's IoU, network against map.
2. ``weights``: per-voxel fusion of all views outside the maps (sum of probabilities, sum of log-probabilities)
   with each observation weighted by its viewing angle and distance: does trusting frontal / close views help?
3. ``rules``: the OctoMap and the voxel grid (``--points``: the 3 cm point map too) with every fusion rule, for
   the network and the oracle, their pixel MIoU gain over each; ``bayes-prior``'s prior is the class frequencies
   of the other two scenes' frames, ``--clamp`` the log-odds floor of ``bayes`` / ``bayes-prior``.
4. ``max``: per voxel, which selector of its views' labels is right (plurality = the ceiling, the most
   confident view = what ``max`` keeps, the summed rules), how well the top-class confidence separates right from
   wrong pixels (AUROC, reliability bins), and the same with the probabilities shuffled among each frame's pixels.

    python scripts/research/fusion_loss_check.py --scene office [--resolution 0.02] [--realism clean]
                                                 [--only maps,weights,rules,max] [--clamp NATS] [--points]
"""

from __future__ import annotations

import argparse
import importlib.util
import itertools
import sys
from pathlib import Path

import numpy as np
from scipy import ndimage

from semmap.eval.pixels import EVERY, map_labels_at
from semmap.eval.semantic import confusion, scores
from semmap.fusion.rules import DEFAULT_LOGODDS_CLAMP, FusionParams, FusionRule
from semmap.geometry import pixel_normals
from semmap.keys import coords_to_keys, pack_keys
from semmap.labels import INDOOR_LABELS
from semmap.maps.point_map import SemanticPointMap
from semmap.maps.semantic_octomap import SemanticOctoMap
from semmap.maps.voxel_grid import SemanticVoxelGrid
from semmap.perception.registry import demo_network
from semmap.types import EMPTY_LABEL, Observation, TopKProbs

K = 40  # bench_fusion's padded label set
REAL = len(INDOOR_LABELS)  # the simulator's classes: the "others" mass of a top-k set spreads over them


def bench_fusion():
    """``benchmarks/bench_fusion.py`` as a module (its scenes, rendering and segmenters)."""
    path = Path(__file__).resolve().parents[2] / "benchmarks" / "bench_fusion.py"
    spec = importlib.util.spec_from_file_location("_bench_fusion", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def near_label_boundary(labels: np.ndarray, r: int = 2) -> np.ndarray:
    """(H, W) pixels within ``r`` px of a pixel of another class."""
    size = 2 * r + 1
    return ndimage.maximum_filter(labels, size=size) != ndimage.minimum_filter(labels, size=size)


def near_depth_edge(depth: np.ndarray, r: int = 2) -> np.ndarray:
    """(H, W) pixels within ``r`` px of a depth jump (neighbours differing by more than max(0.1 m, 5 %)) or a hole."""
    d = np.asarray(depth, np.float64)
    jump = np.zeros(d.shape, bool)
    dx, dy = np.abs(np.diff(d, axis=1)), np.abs(np.diff(d, axis=0))
    tx = dx > np.maximum(0.1, 0.05 * np.minimum(d[:, 1:], d[:, :-1]))
    ty = dy > np.maximum(0.1, 0.05 * np.minimum(d[1:], d[:-1]))
    jump[:, 1:] |= tx
    jump[:, :-1] |= tx
    jump[1:] |= ty
    jump[:-1] |= ty
    return ndimage.binary_dilation(jump | (d <= 0), iterations=r)


def voxel_index(points: np.ndarray, resolution: float) -> tuple[np.ndarray, np.ndarray]:
    """(sorted packed voxel keys, index of each point's voxel among them)."""
    return np.unique(pack_keys(coords_to_keys(points, resolution)), return_inverse=True)


def plurality(inv: np.ndarray, labels: np.ndarray, n: int) -> np.ndarray:
    """Per voxel the most frequent of ``labels`` (ties: the lower id)."""
    return np.bincount(inv * K + labels, minlength=n * K).reshape(n, K).argmax(1)


def most_confident(inv: np.ndarray, labels: np.ndarray, conf: np.ndarray, n: int) -> np.ndarray:
    """Per voxel the label of its most confident observation (what the ``max`` rule ends with)."""
    order = np.lexsort((-conf, inv))
    first = np.r_[True, inv[order][1:] != inv[order][:-1]]
    out = np.zeros(n, np.int64)
    out[inv[order][first]] = labels[order][first]
    return out


def summed(inv: np.ndarray, labels: np.ndarray, probs: np.ndarray, n: int, *, log: bool,
           weights: np.ndarray | None = None) -> np.ndarray:
    """Per voxel the argmax of the (weighted) sum of its observations' class distributions (``log``: of their
    logarithms, i.e. independent-evidence Bayes); each top-k set's remaining mass spreads over the other real
    classes."""
    w = np.ones(len(inv)) if weights is None else weights
    rest = np.clip(1.0 - probs.sum(1), 1e-4, None) / (REAL - labels.shape[1])
    base = np.log(rest) if log else rest
    acc = np.zeros((n, K))
    acc[:, 1:REAL] = np.bincount(inv, w * base, minlength=n)[:, None]
    for j in range(labels.shape[1]):
        ok = (labels[:, j] > 0) & (labels[:, j] < REAL)
        value = np.log(np.clip(probs[ok, j], 1e-6, 1.0)) if log else probs[ok, j]
        np.add.at(acc, (inv[ok], labels[ok, j]), w[ok] * (value - base[ok]))
    acc[:, 0] = -np.inf
    acc[:, REAL:] = -np.inf
    return acc.argmax(1)


def auroc(score: np.ndarray, positive: np.ndarray) -> float:
    """Area under the ROC curve of ``score`` separating ``positive`` from the rest (rank statistic)."""
    ranks = np.empty(len(score))
    ranks[np.argsort(score, kind="stable")] = np.arange(1, len(score) + 1)
    npos, nneg = int(positive.sum()), int((~positive).sum())
    return float((ranks[positive].sum() - npos * (npos + 1) / 2) / max(npos * nneg, 1))


def counterfactual_gain(gt: np.ndarray, net: np.ndarray, mapped: np.ndarray, where: np.ndarray) -> float:
    """The map's pixel MIoU gain over the network if the map took the network's label on ``where``."""
    return scores(confusion(np.where(where, net, mapped), gt, K)).miou - scores(confusion(net, gt, K)).miou


class Scene:
    """One scene's frames and a segmenter's labels, flattened over all frames (labelled pixels only)."""

    def __init__(self, fr, sems: list[TopKProbs], resolution: float) -> None:
        self.fr, self.sems, self.resolution = fr, sems, resolution
        keep = [fr.true_labels(i) != 0 for i in range(len(fr.obs))]
        self.points = np.concatenate([o.points_world[k] for o, k in zip(fr.obs, keep, strict=True)])
        self.gt = np.concatenate([fr.true_labels(i)[k] for i, k in enumerate(keep)]).astype(np.int64)
        self.labels = np.concatenate([s.labels[k] for s, k in zip(sems, keep, strict=True)]).astype(np.int64)
        self.probs = np.concatenate([s.probs[k] for s, k in zip(sems, keep, strict=True)]).astype(np.float64)
        self.frame = np.concatenate([np.full(int(k.sum()), i) for i, k in enumerate(keep)])
        self.keys, self.inv = voxel_index(self.points, resolution)
        n = len(self.keys)
        self.true = plurality(self.inv, self.gt, n)
        self.net_plurality = plurality(self.inv, self.labels[:, 0], n)
        self.pure = (np.bincount(self.inv * K + self.gt, minlength=n * K).reshape(n, K) > 0).sum(1) == 1

    def eval_pixels(self) -> np.ndarray:
        """Mask of the pixels of every EVERY-th frame."""
        return self.frame % EVERY == 0


def maps_report(sc: Scene, resolution: float) -> None:
    """Section 1: lost and won pixels of the OctoMap and the grid, where they lie, counterfactuals, class IoUs."""
    fr, label_set = sc.fr, bench.padded_labels(K)
    maps = {"OctoMap topk": SemanticOctoMap(resolution, label_set=label_set),
            "grid bayes": SemanticVoxelGrid(resolution, label_set=label_set, fusion=FusionParams(FusionRule.BAYES))}
    for obs, sem in zip(fr.obs, sc.sems, strict=True):
        o = Observation(obs.points_world, obs.origin, obs.colors, sem, normals=obs.normals,
                        frame_index=obs.frame_index, keyframe=obs.keyframe)
        for m in maps.values():
            m.integrate(o)
    ev = sc.eval_pixels()
    edge = np.concatenate([
        (near_label_boundary(fr.frames[i].labels.astype(np.int32)) | near_depth_edge(fr.frames[i].depth))
        .reshape(-1)[fr.pixels[i][fr.true_labels(i) != 0]] for i in range(0, len(fr.obs), EVERY)])
    gt, net, vox = sc.gt[ev], sc.labels[ev, 0], sc.inv[ev]
    for name, m in maps.items():
        mapped = map_labels_at(m, sc.points[ev]).astype(np.int64)
        has = mapped != int(EMPTY_LABEL)
        g, n, mp, e, v = gt[has], net[has], mapped[has], edge[has], vox[has]
        sn, sm = scores(confusion(n, g, K)), scores(confusion(mp, g, K))
        lost, won = (n == g) & (mp != g), (n != g) & (mp == g)
        print(f"== {name}, {resolution:g} m: pixels {len(g)} (coverage {has.mean():.3f}); MIoU network {sn.miou:.4f} "
              f"map {sm.miou:.4f} (gain {sm.miou - sn.miou:+.4f}); accuracy {sn.accuracy:.4f} -> {sm.accuracy:.4f}; "
              f"lost {lost.mean():.4f} won {won.mean():.4f} of the pixels")
        for tag, where in (("near a label boundary or depth edge", e), ("in a voxel with two true classes",
                                                                         ~sc.pure[v]),
                           ("in a voxel whose network plurality is wrong", sc.net_plurality[v] != g)):
            print(f"   {tag:44s}: {where.mean():.3f} of all, {where[lost].mean():.3f} of lost, "
                  f"{where[won].mean():.3f} of won; map := network there -> gain "
                  f"{counterfactual_gain(g, n, mp, where):+.4f}")
        cm, cn = confusion(mp, g, K), confusion(n, g, K)
        iou = [np.diag(c) / np.maximum(c.sum(0) + c.sum(1) - np.diag(c), 1) for c in (cn, cm)]
        present = np.flatnonzero(cm.sum(1) > 0)
        order = sorted(present, key=lambda c: iou[1][c] - iou[0][c])
        print("   class IoU network -> map: " + ", ".join(
            f"{INDOOR_LABELS.names[c]} {iou[0][c]:.2f}->{iou[1][c]:.2f}" for c in order))
        worst = order[:3]
        print(f"   map := network on the 3 classes losing most ({', '.join(INDOOR_LABELS.names[c] for c in worst)}) "
              f"-> gain {counterfactual_gain(g, n, mp, np.isin(g, worst)):+.4f}")
        for c in worst:
            said = np.bincount(sc.labels[sc.gt == c, 0], minlength=K) / max(int((sc.gt == c).sum()), 1)
            print(f"      {INDOOR_LABELS.names[c]}: the network's labels over all views: " + ", ".join(
                f"{INDOOR_LABELS.names[i]} {said[i]:.2f}" for i in np.argsort(-said)[:4] if said[i] >= 0.03))


def rules_report(sc: Scene, resolution: float, prior: np.ndarray, clamp: float, points: bool) -> None:
    """Section 3: both maps (and with ``points`` the 3 cm point map) with every fusion rule, fed the same frames;
    ``clamp`` is the log-odds floor of ``bayes`` / ``bayes-prior``."""
    label_set = bench.padded_labels(K)
    maps = {}
    for rule in FusionRule:
        fusion = FusionParams(rule, prior=prior if rule == FusionRule.BAYES_PRIOR else None, logodds_clamp=clamp)
        maps[f"OctoMap {rule.value}"] = SemanticOctoMap(resolution, label_set=label_set, fusion=fusion)
        maps[f"grid {rule.value}"] = SemanticVoxelGrid(resolution, label_set=label_set, fusion=fusion)
        if points:
            maps[f"points {rule.value}"] = SemanticPointMap(0.03, label_set=label_set, fusion=fusion)
    for obs, sem in zip(sc.fr.obs, sc.sems, strict=True):
        o = Observation(obs.points_world, obs.origin, obs.colors, sem, normals=obs.normals,
                        frame_index=obs.frame_index, keyframe=obs.keyframe)
        for m in maps.values():
            m.integrate(o)
    for name, m in maps.items():
        px = bench.pixel_scores(m, sc.fr, sc.sems, K)
        print(f"   {name:19s}: pixel MIoU network {px['pixel_miou_network']:.4f} map {px['pixel_miou_map']:.4f} "
              f"(gain {px['gain']:+.4f}), coverage {px['pixel_coverage']:.4f}")


def weights_report(sc: Scene) -> None:
    """Section 2: per-voxel sums with each observation weighted by viewing angle / distance."""
    fr = sc.fr
    cos, dist = [], []
    for i, f in enumerate(fr.frames):
        keep = fr.true_labels(i) != 0
        pts, org = fr.obs[i].points_world, fr.obs[i].origin
        d = np.linalg.norm(pts - org, axis=1)
        nrm = pixel_normals(f.depth, f.intrinsics, f.T_world_cam, fr.pixels[i])
        c = np.abs(np.sum(nrm * (pts - org) / d[:, None], axis=1))
        cos.append(np.where(np.isfinite(c), c, 0.5)[keep])
        dist.append(d[keep])
    cos, dist = np.concatenate(cos), np.concatenate(dist)
    ok = sc.labels[:, 0] == sc.gt
    for tag, v, edges in (("|cos| of the viewing angle", cos, (0, 0.3, 0.5, 0.7, 0.85, 1.01)),
                          ("distance (m)", dist, (0, 1, 1.5, 2, 2.5, 3, 9))):
        print(f"   network accuracy by {tag}: " + ", ".join(
            f"{lo:g}-{hi:g} {ok[s].mean():.2f} ({s.mean():.2f} of px)"
            for lo, hi in itertools.pairwise(edges) if (s := (v >= lo) & (v < hi)).any()))
    ev = sc.eval_pixels()
    net = scores(confusion(sc.labels[ev, 0], sc.gt[ev], K)).miou
    for log in (False, True):
        for tag, w in (("1", None), ("cos", cos), ("cos^2", cos**2), ("1/d", 1 / dist), ("1/d^2", 1 / dist**2)):
            lab = summed(sc.inv, sc.labels, sc.probs, len(sc.keys), log=log, weights=w)
            m = scores(confusion(lab[sc.inv[ev]], sc.gt[ev], K)).miou
            print(f"   sum of {'log-probs' if log else 'probs':9s} weight {tag:6s}: pixel MIoU {m:.4f} "
                  f"(gain {m - net:+.4f})")


def max_report(sc: Scene, name: str) -> None:
    """Section 3: per-voxel selectors and the confidence's power to separate right from wrong pixels."""
    ok, conf, n = sc.labels[:, 0] == sc.gt, sc.probs[:, 0], len(sc.keys)
    bins = " ".join(f"[{lo:.1f},{lo + 0.1:.1f}) {np.mean(s):.2f} of px, {ok[s].mean():.2f} right"
                    for lo in np.arange(0.3, 1.0, 0.1) if (s := (conf >= lo) & (conf < lo + 0.1)).any())
    print(f"== {name}: accuracy {ok.mean():.3f}; confidence right {conf[ok].mean():.3f} wrong {conf[~ok].mean():.3f};"
          f" AUROC {auroc(conf, ok):.3f}\n   {bins}")
    views = np.bincount(sc.inv, minlength=n)
    for tag, lab in (("plurality (the ceiling)", sc.net_plurality),
                     ("most confident view (max)", most_confident(sc.inv, sc.labels[:, 0], conf, n)),
                     ("sum of probabilities", summed(sc.inv, sc.labels, sc.probs, n, log=False)),
                     ("sum of log-probabilities", summed(sc.inv, sc.labels, sc.probs, n, log=True))):
        right = lab == sc.true
        print(f"   {tag:27s} right in {right.mean():.3f} of {n} voxels ({right[views >= 3].mean():.3f} of those "
              f"seen >= 3 times)")


def shuffled(sems: list[TopKProbs], seed: int = 0) -> list[TopKProbs]:
    """The same labels, each pixel's probabilities taken from a random pixel of the same frame (confidence made
    independent of being right)."""
    rng = np.random.default_rng(seed)
    return [TopKProbs(s.labels, s.probs[rng.permutation(len(s.probs))]) for s in sems]


bench = bench_fusion()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", default="office", choices=[s[0] for s in bench.QUICK_SCENES])
    ap.add_argument("--resolution", type=float, default=0.05)
    ap.add_argument("--realism", default="clean", choices=bench.REALISMS)
    ap.add_argument("--clamp", type=float, default=DEFAULT_LOGODDS_CLAMP, help="log-odds floor of bayes and "
                    "bayes-prior in the rules section")
    ap.add_argument("--points", action="store_true", help="the rules section with the 3 cm point map too")
    ap.add_argument("--only", default="maps,weights,rules,max", help="sections: maps, weights, rules, max "
                    "(comma-separated)")
    args = ap.parse_args()
    index = [s[0] for s in bench.QUICK_SCENES].index(args.scene)
    kind, seed, size = bench.QUICK_SCENES[index]
    fr = bench.render(kind, seed, size, 24, 12, bench.SMALL, args.realism)
    segmenters = dict(bench.sweep_segmenters(bench.padded_labels(K), index, demo_network()))
    sems = {name: bench.segmented(fr, s) for name, s in segmenters.items()}
    only = set(args.only.split(","))
    network = demo_network()
    print(f"{fr.name}, {args.realism}, 24 frames, {args.resolution:g} m; network {network}")
    if "maps" in only:
        maps_report(Scene(fr, sems[network], args.resolution), args.resolution)
    if "weights" in only:
        weights_report(Scene(fr, sems[network], args.resolution))
    if "rules" in only:
        others = [bench.render(k, sd, z, 24, 12, bench.SMALL, args.realism)
                  for k, sd, z in bench.QUICK_SCENES if k != kind]
        prior = bench.class_prior(others, K)
        for name, s in sems.items():
            print(f"-- {name}, log-odds floor {args.clamp:g}")
            rules_report(Scene(fr, s, args.resolution), args.resolution, prior, args.clamp, args.points)
    if "max" in only:
        for name, s in sems.items():
            max_report(Scene(fr, s, args.resolution), name)
            max_report(Scene(fr, shuffled(s), args.resolution), f"{name}, probabilities shuffled")


if __name__ == "__main__":
    main()
