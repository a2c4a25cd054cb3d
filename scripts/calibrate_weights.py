"""Fit the calibration temperature of a trained network's weight file on validation data and write a copy that
carries it (``meta.temperature``, applied by the segmenter unless ``--no-calibration``).

Two kinds of validation data:

- ``--val FOLDER`` (repeatable): training-style folders, scored at the network's training size, the way
  ``semmap train`` fits the temperature at every validation;
- ``--scenes N``: validation scenes 300.. rendered the way ``semmap run`` meets frames (640x480 loops with depth
  noise, every ``--every``-th frame, through the segmenter's own resize and upsampling), like the test frames of
  ``benchmarks/bench_networks.py`` but from scenes disjoint from them and from training.  A temperature fitted at
  the training size can miss the confidence the network has on full frames; this one is fitted where it is used.

    .venv/bin/python scripts/calibrate_weights.py --weights weights/pspnet.pt --val outputs/train-data/val \\
        --out outputs/pspnet-calibrated.pt
    .venv/bin/python scripts/calibrate_weights.py --weights weights/pspnet.pt --scenes 8 --out outputs/pspnet.pt
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from semmap.train.calibrate import calibrate_weights, fitted_record, write_calibrated

#: First seed of the validation scenes (``make_training_data.py``'s validation plan; test scenes are 0-3).
VALIDATION_SEED = 300
#: Frames of each validation loop, as bench_networks' test loops.
LOOP_FRAMES = 300
#: The simulator's void class (``unknown``, id 0), left out as bench_networks leaves it out.
VOID = 0


def validation_frames(scenes: int, every: int, first_seed: int = VALIDATION_SEED) -> list:
    """Every ``every``-th frame of the 300-frame loops of validation scenes ``first_seed``.. (kinds cycling,
    medium, depth noise on), rendered as bench_networks renders its test frames."""
    from semmap.sim.export import simulate_frames
    from semmap.sim.scene import KINDS, generate_scene
    from semmap.sim.trajectory import make_trajectory

    frames = []
    for i, seed in enumerate(range(first_seed, first_seed + scenes)):
        scene = generate_scene(seed, KINDS[i % len(KINDS)], "medium")
        poses = make_trajectory(scene, "loop", LOOP_FRAMES, seed=seed)
        frames += list(simulate_frames(scene, poses[::every], noise=True, seed=seed))
    return frames


def frame_log_probabilities(seg, frames: list, void: int, step: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """(N, K) log-probabilities of ``seg`` at T = 1 and the (N,) true labels at every ``step``-th row and column
    of ``frames``, void pixels left out (log-probabilities are logits up to a constant per pixel)."""
    seg.temperature = 1.0
    logits, labels = [], []
    for f in frames:
        p = seg.probabilities(f.rgb, f.depth if seg.uses_depth else None)[::step, ::step].astype(np.float64)
        lab = f.labels[::step, ::step].astype(np.int64)
        keep = lab != void
        logits.append(np.log(np.clip(p[keep], 1e-12, 1.0)))
        labels.append(lab[keep])
    return np.concatenate(logits), np.concatenate(labels)


def calibrate_on_scenes(weights: Path, out: Path, scenes: int, every: int, threads: int = 2) -> dict:
    """Fit the temperature of ``weights`` on rendered validation scenes and write the calibrated copy to ``out``."""
    from semmap.files.outputs import OutputKind, check_outputs
    from semmap.perception.networks.registry import load_weights
    from semmap.perception.registry import make_segmenter

    check_outputs([("--out", out, OutputKind.FILE)], [("--weights", weights)])
    net = load_weights(weights)
    seg = make_segmenter(net.spec.model, weights=weights, backend="torch", threads=threads, trust_weights=True)
    frames = validation_frames(scenes, every)
    z, y = frame_log_probabilities(seg, frames, VOID)
    record = fitted_record(z, y) | {"images": len(frames), "fitted_on": f"validation scenes {VALIDATION_SEED}-"
                                    f"{VALIDATION_SEED + scenes - 1} rendered at 640x480 through the segmenter, "
                                    f"every {every}th frame"}
    write_calibrated(net, out, record)
    return record


def main(argv: list[str] | None = None) -> None:
    """Fit, write, print the record as JSON."""
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--weights", type=Path, required=True)
    data = parser.add_mutually_exclusive_group(required=True)
    data.add_argument("--val", type=Path, action="append", help="validation folder (repeatable)")
    data.add_argument("--scenes", type=int, help="render this many validation scenes (seeds 300..) instead")
    parser.add_argument("--every", type=int, default=30, help="with --scenes: every n-th frame of each loop")
    parser.add_argument("--out", type=Path, required=True, help="the calibrated copy to write")
    args = parser.parse_args(argv)
    if args.scenes is not None:
        if not (1 <= args.scenes <= 100 and 1 <= args.every <= LOOP_FRAMES):
            parser.error("--scenes must be 1-100 and --every 1-300")
        print(json.dumps(calibrate_on_scenes(args.weights, args.out, args.scenes, args.every)))
    else:
        print(json.dumps(calibrate_weights(args.weights, args.val, args.out)))


if __name__ == "__main__":
    from semmap.cli.terminal import exit_on_errors

    exit_on_errors(main, "calibrate_weights")  # a bad file or option: one line, not a traceback
