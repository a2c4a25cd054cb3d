"""Can one temperature calibrate a shipped network on the test scenes, and do validation scenes find it? (issue 32)

Fits the temperature by NLL (``semmap.train.calibrate.fit_temperature``) on validation scenes rendered the way
``bench_networks.py`` renders its test frames (640x480 with depth noise, the segmenter's own resize; scene seeds
from 300, disjoint from training 100-219 and test 0-3), then scores the test frames' ECE and NLL at that
temperature, and last the temperature fitted on the test pixels themselves (the best one temperature can do).

    python scripts/research/temperature_check.py [--network pspnet] [--scenes 8] [--every 30] [--test-every 60]
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import sys
from pathlib import Path

import numpy as np

from semmap.perception.registry import make_segmenter, shipped_weights
from semmap.sim.export import simulate_frames
from semmap.sim.scene import KINDS, generate_scene
from semmap.sim.trajectory import make_trajectory
from semmap.train.calibrate import fit_temperature

BENCH = Path(__file__).resolve().parents[2] / "benchmarks" / "bench_networks.py"


def bench_networks():
    """benchmarks/bench_networks.py as a module (its test frames and calibration scores)."""
    spec = importlib.util.spec_from_file_location("_bench_networks", BENCH)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def validation_frames(scenes: int, every: int) -> list:
    """Every ``every``-th frame of the 300-frame loops of validation scenes 300.. (kinds cycling, medium)."""
    frames = []
    for i, seed in enumerate(range(300, 300 + scenes)):
        scene = generate_scene(seed, KINDS[i % len(KINDS)], "medium")
        poses = make_trajectory(scene, "loop", 300, seed=seed)
        frames += list(simulate_frames(scene, poses[::every], noise=True, seed=seed))
    return frames


def fitted_temperature(seg, frames: list, void: int, step: int = 4) -> float:
    """NLL temperature of ``seg``'s probabilities (at T = 1) on every ``step``-th row and column of ``frames``."""
    seg.temperature = 1.0
    logits, labels = [], []
    for f in frames:
        p = seg.probabilities(f.rgb, f.depth if seg.uses_depth else None)[::step, ::step].astype(np.float64)
        lab = f.labels[::step, ::step].astype(np.int64)
        keep = lab != void
        logits.append(np.log(np.clip(p[keep], 1e-12, 1.0)))  # log-probabilities: logits up to a constant
        labels.append(lab[keep])
    return fit_temperature(np.concatenate(logits), np.concatenate(labels))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--network", default="pspnet")
    parser.add_argument("--scenes", type=int, default=8, help="validation scenes (seeds 300..)")
    parser.add_argument("--every", type=int, default=30, help="every n-th frame of each validation loop")
    parser.add_argument("--test-every", type=int, default=60, help="bench_networks' test frame step (60 = --quick)")
    args = parser.parse_args()
    bn = bench_networks()
    seg = make_segmenter(args.network, weights=shipped_weights(args.network), backend="torch", threads=2)
    val = validation_frames(args.scenes, args.every)
    test = bn.test_frames(args.test_every)
    out = {"network": args.network, "validation_frames": len(val), "test_frames": len(test)}
    seg.temperature = fitted_temperature(seg, val, bn.VOID)
    out["from_validation"] = bn.calibration(seg, test)
    seg.temperature = fitted_temperature(seg, test, bn.VOID)
    out["from_test"] = bn.calibration(seg, test)
    print(json.dumps(out))


if __name__ == "__main__":
    main()
