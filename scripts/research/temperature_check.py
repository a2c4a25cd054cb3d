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

from semmap.perception.registry import make_segmenter, shipped_weights
from semmap.train.calibrate import fit_temperature

SCRIPTS = Path(__file__).resolve().parents[1]
BENCH = SCRIPTS.parent / "benchmarks" / "bench_networks.py"


def load_module(name: str, path: Path):
    """A script as a module (bench_networks' test frames and scores, calibrate_weights' validation frames)."""
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def bench_networks():
    """benchmarks/bench_networks.py as a module."""
    return load_module("_bench_networks", BENCH)


def fitted_temperature(seg, frames: list, void: int, step: int = 4) -> float:
    """NLL temperature of ``seg``'s probabilities (at T = 1) on every ``step``-th row and column of ``frames``."""
    cal = load_module("_calibrate_weights", SCRIPTS / "calibrate_weights.py")
    return fit_temperature(*cal.frame_log_probabilities(seg, frames, void, step))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--network", default="pspnet")
    parser.add_argument("--scenes", type=int, default=8, help="validation scenes (seeds 300..)")
    parser.add_argument("--every", type=int, default=30, help="every n-th frame of each validation loop")
    parser.add_argument("--test-every", type=int, default=60, help="bench_networks' test frame step (60 = --quick)")
    args = parser.parse_args()
    bn = bench_networks()
    seg = make_segmenter(args.network, weights=shipped_weights(args.network), backend="torch", threads=2)
    cal = load_module("_calibrate_weights", SCRIPTS / "calibrate_weights.py")
    val = cal.validation_frames(args.scenes, args.every)
    test = bn.test_frames(args.test_every)
    out = {"network": args.network, "validation_frames": len(val), "test_frames": len(test)}
    seg.temperature = fitted_temperature(seg, val, bn.VOID)
    out["from_validation"] = bn.calibration(seg, test)
    seg.temperature = fitted_temperature(seg, test, bn.VOID)
    out["from_test"] = bn.calibration(seg, test)
    print(json.dumps(out))


if __name__ == "__main__":
    main()
