"""`semmap adapt` on real frames: the 7-Scenes redkitchen (``../shared/data/7scenes-redkitchen``, 600 frames).

Two cases, each mapped (ground-truth poses, 5 cm, every 5th frame) on frames 0-399, adapted on that run, and scored
on every 10th frame of 400-599 (never seen in adaptation):

- the real default, ``espnetv2+structure``: ESPNetv2 (PASCAL VOC) is adapted, structure stays geometry;
- ``fcn+structure``: the simulator-trained fcn is adapted on a map whose walls, floor and ceiling come mostly from
  geometry.

Score: the project's redkitchen structure yardstick (:mod:`semmap.eval.room_yardstick`: wall, floor and ceiling
from the planes of the ground-truth-posed map, every other pixel with depth ``other``), IoU of wall / floor /
ceiling for the network alone and with structure, before and after. Writes ``--picture`` (default
docs/images/adapt_kitchen.png): held-out frames, colour | before | after for each case, in semmap's class colours.

    python scripts/adapt_7scenes.py [--work DIR] [--steps 300] [--cases espnetv2,fcn]

The last line is JSON: {"script": "adapt_7scenes", "cases": [{"network", "mapped_with", "before", "after",
"cpu_min", "pseudo_labels"}, ...]}.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
from bench_real import KITCHEN  # noqa: E402
from semmap.config import InputConfig, MappingConfig, OutputConfig, RunConfig, SemanticsConfig  # noqa: E402
from semmap.datasets import open_dataset  # noqa: E402
from semmap.eval.room_yardstick import fit_room, label_frame, score_on_yardstick  # noqa: E402
from semmap.labels import INDOOR_LABELS  # noqa: E402
from semmap.perception.registry import make_segmenter  # noqa: E402
from semmap.perception.structure.compose import fold_to  # noqa: E402
from semmap.run.adapt import adapt_run  # noqa: E402
from semmap.runner import run_config  # noqa: E402
from semmap.train.adapt import AdaptSettings  # noqa: E402

#: Frames 0-399 are mapped and adapted on, every 10th of 400-599 scored.
SPLIT, MAP_STRIDE, SCORE_STRIDE = 400, 5, 10
#: Frames of the picture (held out).
PICTURE_FRAMES = (450, 560)


def score(segmenter: str, weights: Path | None, frames: list, yard: list) -> dict:
    """Wall / floor / ceiling IoU of ``segmenter`` on the yardstick frames (in order, with their poses)."""
    seg = make_segmenter(segmenter, weights=weights, threads=1)
    return {k: None if v is None else round(v, 4) for k, v in score_on_yardstick(seg, frames, yard).items()}


def classes(segmenter: str, weights: Path | None, frames: list) -> list[np.ndarray]:
    """Each frame's top class as semmap's class ids (another label set folded into semmap's)."""
    seg = make_segmenter(segmenter, weights=weights, threads=1)
    fold, _ = fold_to(seg.label_set)
    return [fold[np.minimum(seg.segment(f).labels[..., 0], len(fold) - 1)] for f in frames]


def case(network: str, work: Path, steps: int, held: list, yard: list) -> tuple[dict, list]:
    """Map frames 0-399 with ``network+structure``, adapt ``network``, score before and after."""
    out = work / f"{network}-structure"
    config = RunConfig(input=InputConfig(dataset=KITCHEN, format="7scenes", stride=MAP_STRIDE,
                                         max_frames=SPLIT // MAP_STRIDE),
                       mapping=MappingConfig(resolution=0.05),
                       semantics=SemanticsConfig(segmenter=network, add_structure=True, backend="torch"),
                       output=OutputConfig(out=out / "run", preview=False, plots=False, cloud=False))
    if not (out / "run" / "report.json").is_file():
        run_config(config, title=f"adapt_7scenes: {network}+structure")
    adapted = adapt_run(out / "run", AdaptSettings(out=out / "adapted", steps=steps, threads=1),
                        resume=(out / "adapted" / "last.pt").is_file())  # a killed script continues
    cpu_min = adapted.report["cpu_minutes"]  # (process time of the adaptation, kept across a resume)
    row = {"network": network, "mapped_with": f"{network}+structure", "frames_adapted": SPLIT // MAP_STRIDE,
           "frames_scored": len(held), "steps": steps, "cpu_min": round(cpu_min, 2),
           "best_step": adapted.report["best"].get("step"), "pseudo_labels": adapted.report["pseudo_labels"],
           "weights": str(adapted.weights)}
    for when, weights in (("before", None), ("after", adapted.weights)):
        row[when] = {"network": score(network, weights, held, yard),
                     "with_structure": score(f"{network}+structure", weights, held, yard)}
    pictures = [classes(f"{network}+structure", w, [f for f in held if f.index in PICTURE_FRAMES])
                for w in (None, adapted.weights)]
    return row, pictures


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--work", type=Path, default=ROOT / "outputs" / "adapt-7scenes")
    ap.add_argument("--steps", type=int, default=None, help="adaptation steps (default: fcn 300, espnetv2 150, whose "
                    "steps cost about three times as much)")
    ap.add_argument("--cases", default="espnetv2,fcn")
    ap.add_argument("--picture", type=Path, default=ROOT / "docs" / "images" / "adapt_kitchen.png")
    args = ap.parse_args()
    if not KITCHEN.is_dir():
        raise SystemExit(f"needs the 7-Scenes frames: {KITCHEN} not found")
    import torch

    torch.set_num_threads(1)
    frames = list(open_dataset(KITCHEN, "7scenes", stride=SCORE_STRIDE))
    room = fit_room(frames)  # the yardstick's planes from the whole sequence, as bench_real.py fits them
    held = [f for f in frames if f.index >= SPLIT]
    yard = [label_frame(f, room) for f in held]
    rows, panels, titles = [], [], []
    for network in args.cases.split(","):
        steps = args.steps or (150 if network == "espnetv2" else 300)
        row, pictures = case(network, args.work, steps, held, yard)
        rows.append(row)
        panels.append(pictures)
        titles += [f"{network}+structure before", f"{network}+structure after"]
        print(f"{network}: before {json.dumps(row['before'])}  after {json.dumps(row['after'])}  "
              f"{row['cpu_min']:.1f} CPU-min", flush=True)
    _picture(args.picture, [f for f in held if f.index in PICTURE_FRAMES], panels, titles)
    print(json.dumps({"script": "adapt_7scenes", "split": SPLIT, "map_stride": MAP_STRIDE,
                      "score_stride": SCORE_STRIDE, "picture": str(args.picture), "cases": rows}))


def _picture(path: Path, frames: list, panels: list, titles: list[str]) -> None:
    """Rows of held-out frames: colour, then before | after of each case, with the legend of the classes shown."""
    from semmap.viz.preview import side_by_side, with_class_legend, write_png

    palette = np.asarray(INDOOR_LABELS.colors, np.uint8)
    rows = []
    for j, f in enumerate(frames):
        images = [f.rgb] + [palette[p[when][j]] for p in panels for when in (0, 1)]
        rows.append(side_by_side(images, ["colour", *titles] if j == 0 else [""] * len(images)))
    shown = np.unique(np.concatenate([np.unique(p[w][j]) for p in panels for w in (0, 1) for j in range(len(frames))]))
    path.parent.mkdir(parents=True, exist_ok=True)
    write_png(path, with_class_legend(np.concatenate(rows), shown, INDOOR_LABELS))


if __name__ == "__main__":
    main()
