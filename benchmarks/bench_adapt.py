"""`semmap adapt` under a real domain shift, in simulation: networks trained on `clean` scenes meet `kinect` and
`hard` recordings of scenes they never saw, adapt on the first part of each walk and are scored on its last part.

Per scene (seed, room kind, realism; seeds 5-8, disjoint from training 100-219 / 400+, validation 300-307, the
test scenes 0-3 and the development scene 4 the settings were chosen on), a 300-frame hand-held loop at 320x240:

1. `semmap run` on frames 0-199 with the shipped network, then `semmap adapt` on that run (CPU minutes: the
   process time of the whole adaptation, one torch thread, replay frames read from the cache after the first
   scene);
2. `semmap run` on all 300 frames with the shipped network (the first map) and with the adapted one (the re-mapped
   map);
3. scored at the pixels of every 5th frame of 210-299 (never seen in adaptation; a pixel with a depth and a true
   label), as the map-at-pixel evaluation does: the network before and after on all those pixels, the first and the
   re-mapped map where both maps have a class;
4. forgetting: the network's MIoU on `bench_networks.py`'s held-out `clean` test frames (scene seeds 0-3, every
   10th frame of each loop, 640x480) before minus after, in points.

The pseudo-labels' own quality (accuracy and MIoU on the kept pixels against the network's there) and the first
map's fusion ceiling on the adaptation frames say how much the map can teach.

    python benchmarks/bench_adapt.py [--quick] [--networks fcn] [--scenes 5,6] [--steps 300] [--work DIR]

The last line is JSON: {"bench": "adapt", "results": [{"scene", "shift", "network", "miou_before", "miou_after",
"map_before", "map_after", "forgetting", "cpu_min", ...}, ...]}
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from bench_networks import evaluate as network_scores
from bench_networks import test_frames
from semmap.config import InputConfig, MappingConfig, OutputConfig, RunConfig, SemanticsConfig
from semmap.datasets import open_dataset
from semmap.eval.pixels import frame_sample, map_labels_at
from semmap.eval.semantic import confusion, scores
from semmap.perception.registry import make_segmenter, shipped_weights
from semmap.run.adapt import adapt_run
from semmap.runner import run_config
from semmap.sim.export import simulate_sequence
from semmap.train.adapt import AdaptSettings
from semmap.types import EMPTY_LABEL

ROOT = Path(__file__).resolve().parents[1]
#: (scene seed, room kind, realism) of the shifted scenes; medium rooms, the hand-held loop.
SCENES = ((5, "kitchen", "kinect"), (6, "living_room", "hard"), (7, "bedroom", "kinect"), (8, "office", "hard"))
FRAMES, SPLIT, GAP, EVERY = 300, 200, 10, 5
IMAGE = (320, 240)
#: Every n-th frame of each test loop the forgetting is measured on (bench_networks.py's full set: 10).
FORGET_STEP = 10


def sequence(work: Path, seed: int, kind: str, realism: str, frames: int) -> Path:
    """The scene's recording (rendered once into ``work``)."""
    root = work / f"{kind}-medium-seed{seed}-loop-{realism}"
    if not (root / "scene.json").is_file():
        simulate_sequence(root, scene_seed=seed, kind=kind, size="medium", trajectory="loop", frames=frames,
                          image_size=IMAGE, realism=realism)
    return root


def mapped(seq: Path, out: Path, network: str, weights: Path | None, frames: int | None):
    """`semmap run` of the first ``frames`` frames (all: None) with ``network`` (its shipped weights: None)."""
    config = RunConfig(input=InputConfig(dataset=seq, max_frames=frames), mapping=MappingConfig(),
                       semantics=SemanticsConfig(segmenter=network, weights=weights, backend="torch"),
                       output=OutputConfig(out=out, preview=False, plots=False, cloud=False))
    return run_config(config, title=f"bench_adapt: {out.name}")


def held_out_scores(seq: Path, network: str, weights: dict[str, Path | None], maps: dict, threads: int,
                    first: int, every: int) -> dict:
    """Network and map MIoU at the pixels of every ``every``-th frame from ``first`` on: the networks on all
    labelled pixels with a depth, the maps where both have a class."""
    segs = {key: make_segmenter(network, weights=w, backend="torch", threads=threads) for key, w in weights.items()}
    k = len(next(iter(segs.values())).label_set)
    conf = {key: np.zeros((k, k), np.int64) for key in (*segs, *(f"map_{m}" for m in maps))}
    frames = 0
    for frame in open_dataset(seq):
        if frame.index < first or (frame.index - first) % every or frame.labels is None:
            continue
        frames += 1
        sample = None
        for key, seg in segs.items():
            s = frame_sample(frame, frame.T_world_cam, seg.segment(frame))
            sample = sample or s
            conf[key] += confusion(s.net, s.gt, k)
        labels = {m: map_labels_at(mp, sample.points) for m, mp in maps.items()}
        both = np.logical_and.reduce([lab != EMPTY_LABEL for lab in labels.values()])
        for m, lab in labels.items():
            conf[f"map_{m}"] += confusion(lab[both], sample.gt[both], k)
    out = {key: round(scores(c).miou, 4) for key, c in conf.items()}
    out["frames_scored"] = frames
    return out


def forgetting_miou(network: str, weights: Path | None, frames, threads: int) -> float:
    seg = make_segmenter(network, weights=weights, backend="torch", threads=threads)
    return network_scores(seg, frames)[0]["miou"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="two scenes, 100 steps, forgetting on every 30th frame")
    ap.add_argument("--networks", default="fcn", help="comma-separated trained networks (default fcn)")
    ap.add_argument("--scenes", default=None, help="comma-separated scene seeds of " +
                    ", ".join(f"{s} ({k}, {r})" for s, k, r in SCENES))
    ap.add_argument("--steps", type=int, default=None, help="adaptation steps (default 300; --quick 100)")
    ap.add_argument("--threads", type=int, default=1, help="torch threads (1: CPU time is the work, not spinning)")
    ap.add_argument("--work", type=Path, default=ROOT / "outputs" / "bench-adapt",
                    help="folder of the recordings, runs and adapted weights (kept: a rerun reuses the recordings)")
    args = ap.parse_args()
    import torch

    torch.set_num_threads(args.threads)
    steps = args.steps or (100 if args.quick else 300)
    chosen = SCENES[:2] if args.quick else SCENES
    if args.scenes:
        wanted = {int(s) for s in args.scenes.split(",")}
        chosen = tuple(s for s in SCENES if s[0] in wanted)
    work = args.work
    work.mkdir(parents=True, exist_ok=True)
    forget_frames = test_frames(30 if args.quick else FORGET_STEP)
    results = []
    for network in (n.strip() for n in args.networks.split(",")):
        shipped = shipped_weights(network)
        test_before = forgetting_miou(network, None, forget_frames, args.threads)
        for seed, kind, realism in chosen:
            t0 = time.perf_counter()
            seq = sequence(work, seed, kind, realism, FRAMES)
            name = seq.name
            base = work / f"{name}-{network}"
            first = mapped(seq, base / "first", network, None, SPLIT)
            adapted = adapt_run(base / "first", AdaptSettings(out=base / "adapted", steps=steps, threads=args.threads),
                                resume=(base / "adapted" / "last.pt").is_file())  # a killed benchmark continues
            cpu_min = adapted.report["cpu_minutes"]  # (process time of the adaptation, kept across a resume)
            before = mapped(seq, base / "before", network, None, None)
            after = mapped(seq, base / "after", network, adapted.weights, None)
            held = held_out_scores(seq, network, {"before": None, "after": adapted.weights},
                                   {"before": before.maps[0], "after": after.maps[0]}, args.threads,
                                   SPLIT + GAP, EVERY)
            test_after = forgetting_miou(network, adapted.weights, forget_frames, args.threads)
            p = adapted.report["pseudo_labels"]
            row = {"scene": f"{kind}-medium-seed{seed}", "shift": realism, "network": network,
                   "miou_before": held["before"], "miou_after": held["after"],
                   "map_before": held["map_before"], "map_after": held["map_after"],
                   "forgetting": round(100 * (test_before - test_after), 2), "cpu_min": round(cpu_min, 2),
                   "gain_points": round(100 * (held["after"] - held["before"]), 2),
                   "map_gain_points": round(100 * (held["map_after"] - held["map_before"]), 2),
                   "test_miou_before": test_before, "test_miou_after": test_after,
                   "frames_adapted": SPLIT, "frames_scored": held["frames_scored"], "steps": steps,
                   "best_step": adapted.report["best"].get("step"),
                   "pseudo_coverage": p["coverage"], "pseudo_miou": p.get("miou"),
                   "pseudo_network_miou": p.get("network_miou"), "pseudo_accuracy": p.get("accuracy"),
                   "pseudo_network_accuracy": p.get("network_accuracy"),
                   "first_map_gain": first.report.get("pixel_gain"),
                   "ceiling_voxel_accuracy": first.report.get("ceiling_voxel_accuracy"),
                   "unreachable_share": first.report.get("unreachable_share"),
                   "weights": str(adapted.weights), "shipped": str(shipped), "seconds": round(time.perf_counter() - t0)}
            results.append(row)
            print(f"{row['scene']} {realism} {network}: network {row['miou_before']:.3f} -> {row['miou_after']:.3f} "
                  f"({row['gain_points']:+.1f}), map {row['map_before']:.3f} -> {row['map_after']:.3f} "
                  f"({row['map_gain_points']:+.1f}), forgetting {row['forgetting']:+.2f}, "
                  f"{row['cpu_min']:.1f} CPU-min; "
                  f"pseudo-labels MIoU {p.get('miou')} vs network {p.get('network_miou')} on "
                  f"{p['coverage']:.0%} of the pixels", flush=True)
    print(json.dumps({"bench": "adapt", "frames": FRAMES, "split": SPLIT, "scored_from": SPLIT + GAP,
                      "every": EVERY, "image": "x".join(map(str, IMAGE)), "threads": args.threads,
                      "forget_frames": len(forget_frames), "results": results}))


if __name__ == "__main__":
    main()
