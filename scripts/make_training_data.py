"""Render the simulated training and validation scenes the shipped networks were trained on (weights/).

Seeds are disjoint from every scene the tests, benchmarks and the demo use (scene seeds 0-9):

* train: scene seeds 100-219, 120 scenes cycling the four kinds, three sizes and four trajectory kinds,
  17 frames each spread over 20 s of the path, 2040 frames (many scenes, few frames each: a network trained
  on 40 scenes x 50 frames scored 0.61 mIoU on its training scenes but 0.36 on unseen ones);
* val:   scene seeds 300-307, two per kind, medium, loop, 10 frames each (best-checkpoint selection only);
* test:  scene seeds 0-3 (office, kitchen, living_room, bedroom; medium; the demo's loop) are rendered on the
  fly by benchmarks/bench_networks.py at 640x480 and never written here.

Frames are rendered at 640x480 and stored at the training input size (default 160x120), reduced as the
segmenter reduces camera images.  Deterministic: same arguments, same bytes.  The full set takes a while
(2,120 frames); ``--scenes`` and ``--frames`` make a small one for a first try (the first scenes of each plan,
fewer frames each):

    .venv/bin/python scripts/make_training_data.py --out outputs/train-data [--image-size 160x120]
    .venv/bin/python scripts/make_training_data.py --out outputs/train-tiny --scenes 4 --frames 5   # 30 frames
"""

from __future__ import annotations

import argparse
import shutil
import time
from pathlib import Path

from semmap.errors import SimulationError
from semmap.sim.export import simulate_sequence
from semmap.train.sim_data import (
    EXTRA_SEEDS,
    PATH_SECONDS,
    TRAIN_FRAMES,
    TRAIN_SEEDS,
    VAL_FRAMES,
    train_plan,
    val_plan,
)


def realism_of(choice: str, i: int) -> str:
    """The realism preset of the ``i``-th scene: ``choice``, or with ``mixed`` the three in turn."""
    return ("clean", "kinect", "hard")[i % 3] if choice == "mixed" else choice


def render(out: Path, plan, frames: int, image_size: tuple[int, int], realism: str = "clean") -> None:
    for i, scene in enumerate(plan):
        seed, kind, size, trajectory = scene.seed, scene.kind, scene.size, scene.trajectory
        preset = realism_of(realism, i)
        tag = "" if preset == "clean" else f"-{preset}"
        folder = out / f"{scene.name}{tag}"
        if (folder / "scene.json").is_file():
            continue
        t0 = time.perf_counter()
        try:
            simulate_sequence(folder, scene_seed=seed, kind=kind, size=size, trajectory=trajectory, frames=frames,
                              image_size=image_size, fps=frames / PATH_SECONDS, realism=preset)
        except SimulationError as exc:  # a desk/orbit path may not fit a scene: fall back to the room loop
            print(f"{folder.name}: {exc}; using a loop", flush=True)
            shutil.rmtree(folder, ignore_errors=True)
            folder = out / f"{kind}-{size}-seed{seed}-loop{tag}"
            simulate_sequence(folder, scene_seed=seed, kind=kind, size=size, trajectory="loop", frames=frames,
                              image_size=image_size, fps=frames / PATH_SECONDS, realism=preset)
        print(f"{folder.name}: {frames} frames in {time.perf_counter() - t0:.1f} s", flush=True)


def main(argv: list[str] | None = None) -> None:
    """Render the training and validation scenes into ``--out`` (scenes already there are kept)."""
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--image-size", default="160x120", help="stored frame size WIDTHxHEIGHT")
    parser.add_argument("--scenes", type=int, default=None,
                        help=f"training scenes (the first of {len(TRAIN_SEEDS)}; validation gets half as many, "
                             f"at least 1; default all)")
    parser.add_argument("--frames", type=int, default=None,
                        help=f"frames per scene (default {TRAIN_FRAMES} for training, {VAL_FRAMES} for validation)")
    parser.add_argument("--extra", type=int, default=0,
                        help=f"also render this many more training scenes into OUT/train-extra (seeds from "
                             f"{EXTRA_SEEDS.start}, the same plan; at most {len(EXTRA_SEEDS)})")
    parser.add_argument("--realism", default="clean", choices=("clean", "kinect", "hard", "mixed"),
                        help="the simulator's realism preset of the training scenes (mixed: clean, kinect and hard "
                             "in turn); validation stays clean, as the shipped networks were selected")
    args = parser.parse_args(argv)
    w, h = (int(v) for v in args.image_size.lower().split("x"))
    if (args.scenes is not None and args.scenes < 1) or (args.frames is not None and args.frames < 1):
        parser.error("--scenes and --frames must be at least 1")
    if not 0 <= args.extra <= len(EXTRA_SEEDS):
        parser.error(f"--extra must be 0-{len(EXTRA_SEEDS)}")
    train, val = train_plan(), val_plan()
    if args.scenes is not None:
        train, val = train[: args.scenes], val[: max(1, args.scenes // 2)]
    render(args.out / "train", train, args.frames or TRAIN_FRAMES, (w, h), args.realism)
    render(args.out / "val", val, args.frames or VAL_FRAMES, (w, h))
    if args.extra:
        extra = train_plan(EXTRA_SEEDS)[: args.extra]
        render(args.out / "train-extra", extra, args.frames or TRAIN_FRAMES, (w, h), args.realism)


if __name__ == "__main__":
    from semmap.cli.terminal import exit_on_errors

    exit_on_errors(main, "make_training_data")  # a bad file or option: one line, not a traceback
