"""The papers' networks as semmap trains and ships them (weights/), on held-out simulated scenes.

Test frames: scene seeds 0-3 (office, kitchen, living_room, bedroom; medium; the demo's 300-frame loop), disjoint
from the training (100-219; 400 on with make_training_data.py --extra) and validation (300-307) scenes, rendered at
640x480 with depth noise; every 10th frame, 120 in all (every 60th with --quick: 20 frames).  For every shipped
network and runtime (PyTorch, ONNX Runtime): MPA and MIoU (eqs. 11-12 of the CBAM paper, classes present in the
ground truth, void pixels left out) of the top class at 640x480, parameters, and ms per 640x480 frame through the
segmenter `semmap run` uses (resize, network, softmax, sampling at every pixel, top-3).  ESPNetv2 (PASCAL VOC
weights in ../shared) is the peer: timed in the same run, scored on the classes VOC shares with the simulator
(``miou_shared``; every network gets that column too).  ONNX rows report the share of pixels whose top class equals
PyTorch's.  PyTorch rows also give the calibration of the probabilities on the test pixels: expected calibration
error (15 bins) and NLL with the temperature stored with the weights (``ece``, ``nll``) and without
(``ece_uncalibrated``, ``nll_uncalibrated``); ``init`` says how the network started (``scratch`` or --init).
Spread: ``miou_ci95`` is a 95 % bootstrap interval of the MIoU over the test frames (1,000 resamples of whole
frames, the confusion summed over each resample); ``comparisons`` gives the papers' two claims (CBAM-PSPNet against
PSPNet, the RGB-D net against its colour-only twin) as the MIoU difference with a paired interval (the same
resampled frames for both networks), so a reader can tell a difference from noise.

Real frames: where the 7-Scenes redkitchen frames are beside the repository, each network's top class is also
scored against the project's structure yardstick (``semmap.eval.room_yardstick``: wall and floor from the
ground-truth-posed map's planes, every 20th frame): ``real_wall_iou``, ``real_floor_iou`` on the PyTorch rows, the
one real measure of a network trained on simulated rooms that the project holds (``--no-real`` leaves it out).

Timings depend on the machine's load: the development machine is shared (2 cores, other jobs running).
The last line is JSON: {"bench": "networks", "results": [{"model", "input", "params", "mpa", "miou",
"ms_per_frame", "runtime", "init", "ece", "nll", ...}, ...]}

    python benchmarks/bench_networks.py [--quick] [--threads 2] [--weights-dir weights] [--networks pspnet,fcn]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from semmap.eval.room_yardstick import score_on_yardstick
from semmap.eval.semantic import confusion, scores
from semmap.labels import INDOOR_LABELS
from semmap.perception.networks.registry import count_parameters, load_weights
from semmap.perception.registry import TRAINED_NETWORKS, make_segmenter, shipped_weights_dir
from semmap.sim.export import simulate_frames
from semmap.sim.scene import generate_scene
from semmap.sim.trajectory import make_trajectory
from semmap.train.calibrate import calibration_scores
from semmap.types import Frame

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
SEVEN_SCENES = SHARED / "data" / "7scenes-redkitchen"
ESPNETV2 = Path(__file__).resolve().parents[1] / "weights" / "espnetv2" / "espnetv2_s_2.0_pascal_384x384.pth"
#: Held-out test scenes: (scene seed, kind), medium size, the demo's loop trajectory of 300 frames.
TEST_SCENES = ((0, "office"), (1, "kitchen"), (2, "living_room"), (3, "bedroom"))
TRAJECTORY_FRAMES = 300
#: PASCAL VOC class -> simulator class, for the classes both have.
VOC_TO_INDOOR = {"chair": "chair", "diningtable": "table", "sofa": "sofa", "tvmonitor": "monitor",
                 "bottle": "bottle", "pottedplant": "plant", "person": "person"}
VOID = 0
#: Test pixels the calibration scores use: every n-th row and column.
CALIBRATION_STEP = 4
#: The papers' claims, as (network, the network it should beat by the points given).
CLAIMS = (("cbam-pspnet", "pspnet", 1.0), ("rgbd-net", "rgb-only", 3.0))
BOOTSTRAP_RESAMPLES = 1000


def bootstrap_mious(frame_confusions: np.ndarray, picks: np.ndarray) -> np.ndarray:
    """MIoU of each resample: ``picks`` (R, F) frame indices, ``frame_confusions`` (F, K, K)."""
    out = np.empty(len(picks))
    for r, idx in enumerate(picks):
        out[r] = scores(frame_confusions[idx].sum(axis=0), ignore=VOID).miou
    return out


def spread(per_frame: dict[str, np.ndarray], seed: int = 0) -> tuple[dict[str, list[float]], list[dict]]:
    """95 % bootstrap interval of each network's MIoU and the paired intervals of the papers' claims."""
    if not per_frame:
        return {}, []
    n = len(next(iter(per_frame.values())))
    picks = np.random.default_rng(seed).integers(0, n, size=(BOOTSTRAP_RESAMPLES, n))
    boot = {name: bootstrap_mious(c, picks) for name, c in per_frame.items()}
    intervals = {name: [round(float(v), 4) for v in np.percentile(b, [2.5, 97.5])] for name, b in boot.items()}
    claims = []
    for better, base, points in CLAIMS:
        if better in boot and base in boot:
            diff = 100 * (boot[better] - boot[base])
            point = 100 * (scores(per_frame[better].sum(axis=0), ignore=VOID).miou
                           - scores(per_frame[base].sum(axis=0), ignore=VOID).miou)
            lo, hi = np.percentile(diff, [2.5, 97.5])
            claims.append({"network": better, "against": base, "claimed_points": points,
                           "miou_points": round(float(point), 2),
                           "ci95_points": [round(float(lo), 2), round(float(hi), 2)],
                           "claim_met": bool(point >= points), "above_noise": bool(lo > 0)})
    return intervals, claims


def test_frames(step: int) -> list[Frame]:
    """Every ``step``-th frame of the test scenes' loops."""
    frames = []
    for seed, kind in TEST_SCENES:
        scene = generate_scene(seed, kind, "medium")
        poses = make_trajectory(scene, "loop", TRAJECTORY_FRAMES, seed=seed)
        frames += list(simulate_frames(scene, poses[::step], noise=True, seed=seed))
    return frames


def shared_ids(to_indoor: np.ndarray) -> np.ndarray:
    """Map simulator ids to 0 (other) or themselves for the classes VOC shares."""
    keep = np.zeros(len(INDOOR_LABELS), np.int64)
    for name in VOC_TO_INDOOR.values():
        keep[INDOOR_LABELS.id_of(name)] = INDOOR_LABELS.id_of(name)
    return keep[to_indoor]


def evaluate(seg, frames: list[Frame], voc: bool = False) -> tuple[dict, list[np.ndarray], np.ndarray]:
    """Scores, ms per frame (after one warm-up frame), the top-class images of a segmenter and its confusion per
    frame (F, K, K; empty for the VOC peer)."""
    k = len(INDOOR_LABELS)
    conf = np.zeros((k, k), np.int64)
    conf_shared = np.zeros((k, k), np.int64)
    lut = None
    if voc:
        lut = np.zeros(len(seg.label_set), np.int64)
        for voc_name, name in VOC_TO_INDOOR.items():
            lut[seg.label_set.id_of(voc_name)] = INDOOR_LABELS.id_of(name)
    seg.segment(frames[0])
    preds, elapsed, per_frame = [], 0.0, []
    for f in frames:
        t0 = time.perf_counter()
        top = seg.segment(f).labels[..., 0]
        elapsed += time.perf_counter() - t0
        pred = np.where(top < len(seg.label_set), top, 0).astype(np.int64)
        if lut is not None:
            pred = lut[pred]
        preds.append(pred)
        if not voc:
            per_frame.append(confusion(pred, f.labels, k, ignore=VOID))
            conf += per_frame[-1]
        gt = f.labels.astype(np.int64)
        conf_shared += confusion(shared_ids(pred), np.where(gt == VOID, -1, shared_ids(gt)), k, ignore=-1)
    shared = scores(conf_shared, ignore=None)
    shared_iou = shared.iou[[INDOOR_LABELS.id_of(n) for n in VOC_TO_INDOOR.values()]]
    out = {"ms_per_frame": round(1e3 * elapsed / len(frames), 1),
           "miou_shared": round(float(np.nanmean(shared_iou)), 4)}
    if not voc:
        s = scores(conf, ignore=VOID)
        out |= {"mpa": round(s.mpa, 4), "miou": round(s.miou, 4), "pixel_accuracy": round(s.accuracy, 4)}
    return out, preds, np.array(per_frame)


def calibration(seg, frames: list[Frame], step: int = CALIBRATION_STEP) -> dict:
    """ECE (15 bins) and NLL of the segmenter's probabilities on the test pixels (every ``step``-th row and
    column, void left out), with its stored temperature and with none (``*_uncalibrated``)."""
    stored = seg.temperature
    out = {"temperature": stored}
    for key, t in (("", stored), ("_uncalibrated", 1.0)):
        seg.temperature = t
        probs, labels = [], []
        for f in frames:
            p = seg.probabilities(f.rgb, f.depth if seg.uses_depth else None)[::step, ::step].astype(np.float32)
            lab = f.labels[::step, ::step].astype(np.int64)
            keep = lab != VOID
            probs.append(p[keep])
            labels.append(lab[keep])
        sc = calibration_scores(np.concatenate(probs), np.concatenate(labels))
        out |= {f"ece{key}": sc["ece"], f"nll{key}": sc["nll"]}
    seg.temperature = stored
    return out


def real_frames() -> tuple[list[Frame], list[np.ndarray]] | None:
    """Every 20th 7-Scenes redkitchen frame and its structure yardstick labels (None without the frames)."""
    if not SEVEN_SCENES.is_dir():
        print(f"no real-frame column: {SEVEN_SCENES} not found")
        return None
    from semmap.datasets import open_dataset
    from semmap.eval.room_yardstick import fit_room, label_frame

    frames = list(open_dataset(SEVEN_SCENES, "7scenes", stride=20))
    room = fit_room(frames)
    return frames, [label_frame(f, room) for f in frames]


def _rounded(v: float | None) -> float | None:
    return None if v is None else round(v, 4)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="every 60th frame of each test loop (20 frames)")
    parser.add_argument("--threads", type=int, default=2, help="CPU threads of both runtimes")
    parser.add_argument("--weights-dir", type=Path, default=None, help="folder of <network>.pt (default: weights/)")
    parser.add_argument("--networks", default=None, help="comma-separated networks to run (default: all shipped)")
    parser.add_argument("--no-peer", action="store_true", help="leave out the ESPNetv2 VOC peer")
    parser.add_argument("--no-real", action="store_true", help="leave out the 7-Scenes structure yardstick")
    args = parser.parse_args()
    wdir = args.weights_dir or shipped_weights_dir()
    t0 = time.perf_counter()
    frames = test_frames(60 if args.quick else 10)
    print(f"{len(frames)} test frames (scene seeds {[s for s, _ in TEST_SCENES]}) rendered in "
          f"{time.perf_counter() - t0:.1f} s; machine shared: timings are indicative")
    real = None if args.no_real else real_frames()
    results, per_frame = [], {}
    wanted = TRAINED_NETWORKS if args.networks is None else tuple(n.strip() for n in args.networks.split(","))
    for name in (n for n in TRAINED_NETWORKS if n in wanted):
        path = wdir / f"{name}.pt"
        if not path.is_file():
            print(f"skipping {name}: {path} not found")
            continue
        loaded = load_weights(path)
        init = loaded.meta.get("init") or (loaded.meta.get("settings") or {}).get("init") or "scratch"
        base = {"model": loaded.spec.describe(), "network": name, "init": init,
                "input": "x".join(map(str, loaded.input_size)), "params": count_parameters(loaded.model)}
        torch_preds = None
        for runtime in ("torch", "onnx"):
            seg = make_segmenter(name, weights=path, backend=runtime, threads=args.threads)
            row, preds, confusions = evaluate(seg, frames)
            row = base | row | {"runtime": runtime}
            if torch_preds is None:
                torch_preds = preds
                per_frame[name] = confusions
                row |= calibration(seg, frames)  # the same probabilities in both runtimes: scored once
                if real is not None:
                    ious = score_on_yardstick(seg, *real)
                    row |= {"real_wall_iou": _rounded(ious["wall"]), "real_floor_iou": _rounded(ious["floor"])}
            else:
                same = np.mean([np.mean(a == b) for a, b in zip(preds, torch_preds, strict=True)])
                row["agreement_with_torch"] = round(float(same), 5)
            results.append(row)
            print(f"{row['model']:26s} {runtime:5s} {row['input']:>7s}  MIoU {row['miou']:.3f}  MPA {row['mpa']:.3f}"
                  f"  shared-class MIoU {row['miou_shared']:.3f}  {row['ms_per_frame']:6.1f} ms/frame"
                  + (f"  agrees with torch on {100 * row['agreement_with_torch']:.2f} % of pixels"
                     if "agreement_with_torch" in row else "")
                  + (f"  ECE {row['ece_uncalibrated']:.3f} -> {row['ece']:.3f}, NLL {row['nll_uncalibrated']:.3f} -> "
                     f"{row['nll']:.3f} (T {row['temperature']:g})" if "ece" in row else "")
                  + (f"  real frames: wall IoU {row['real_wall_iou']}, floor {row['real_floor_iou']}"
                     if "real_wall_iou" in row else ""))
    if args.no_peer:
        pass
    elif ESPNETV2.is_file():
        for runtime in ("torch", "onnx"):
            seg = make_segmenter("espnetv2", weights=ESPNETV2, backend=runtime, threads=args.threads)
            row, _, _ = evaluate(seg, frames, voc=True)
            row = {"model": "espnetv2-s2.0-voc", "network": "espnetv2", "input": "432x320",
                   "params": count_parameters(seg._model), "mpa": None, "miou": None, "runtime": runtime} | row
            results.append(row)
            print(f"{row['model']:26s} {runtime:5s} {row['input']:>7s}  shared-class MIoU {row['miou_shared']:.3f}"
                  f"  {row['ms_per_frame']:6.1f} ms/frame (peer)")
        peer = {r["runtime"]: r["ms_per_frame"] for r in results if r["network"] == "espnetv2"}
        for r in results:
            if r["network"] != "espnetv2" and r["runtime"] in peer:
                r["speed_vs_espnetv2"] = round(peer[r["runtime"]] / r["ms_per_frame"], 2)
    else:
        print(f"skipping the ESPNetv2 peer: {ESPNETV2} not found")
    intervals, claims = spread(per_frame)
    for r in results:
        if r["runtime"] == "torch" and r["network"] in intervals:
            r["miou_ci95"] = intervals[r["network"]]
    for c in claims:
        print(f"{c['network']} - {c['against']}: {c['miou_points']:+.2f} MIoU points, 95 % interval "
              f"[{c['ci95_points'][0]:+.2f}, {c['ci95_points'][1]:+.2f}] (claimed {c['claimed_points']:+.1f}: "
              f"{'met' if c['claim_met'] else 'not met'}; {'above' if c['above_noise'] else 'within'} the noise)")
    print(json.dumps({"bench": "networks", "frames": len(frames), "frame": "640x480", "threads": args.threads,
                      "test_scenes": [f"{k}-medium-seed{s}-loop" for s, k in TEST_SCENES], "results": results,
                      "comparisons": claims}))


if __name__ == "__main__":
    main()
