"""Real frames: the 7-Scenes redkitchen structure yardstick (issue 45) for each segmenter, and a map of the kitchen
built with the real default, measured on its floor plane and table top.

- **Yardstick** (:mod:`semmap.eval.room_yardstick`): wall, floor and ceiling from the planes of the
  ground-truth-posed map, rendered into every 10th frame; each segmenter's top class there scored as wall /
  floor / ceiling IoU over the pixels with depth (a cabinet front called wall counts against it). Structure runs
  twice: on single frames (no pose, up from each frame) and as ``semmap run`` uses it (posed, in order).
- **Map** (``semmap run`` with no ``--segmenter``: espnetv2+structure, ground-truth poses, 5 cm, every 5th
  frame): the share of the voxels on the floor plane labelled ``floor``, the share of ``floor`` voxels on the
  floor plane, and the precision of ``table`` voxels (on the table top's plane), with the map's largest classes.

The last line is JSON: {"bench": "real", "yardstick": {...}, "results": [{"segmenter", "wall", "floor",
"ceiling", "frames", "ms_per_frame"}], "map": {...}}.

    python benchmarks/bench_real.py [--quick] [--segmenters structure,espnetv2+structure,fcn,...] [--no-map]
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

from semmap.datasets import open_dataset
from semmap.eval.room_yardstick import (
    CEILING_ID,
    FLOOR_ID,
    OTHER_ID,
    WALL_ID,
    fit_room,
    label_frame,
    score_on_yardstick,
)
from semmap.labels import INDOOR_LABELS
from semmap.perception.registry import make_segmenter
from semmap.perception.structure.compose import fold_to

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
KITCHEN = SHARED / "data" / "7scenes-redkitchen"
DEFAULT_SEGMENTERS = ("structure", "espnetv2+structure", "espnetv2", "fcn", "fcn+structure", "rgbd-net")
#: A voxel lies on a plane when its centre is within half its diagonal (a cube the plane cuts, at any tilt) plus
#: this (metres: the yardstick plane's own spread over the sequence) of it.
ON_PLANE_M = 0.03


def score(name: str, frames: list, yard: list[np.ndarray], *, posed: bool = True) -> dict:
    seg = make_segmenter(name, backend="onnx")
    t0 = time.perf_counter()
    ious = score_on_yardstick(seg, frames, yard, posed=posed)
    t = time.perf_counter() - t0
    return {"segmenter": name + ("" if posed else " (single frames)"), "frames": len(frames),
            **{k: None if v is None else round(v, 4) for k, v in ious.items()},
            "ms_per_frame": round(t / len(frames) * 1e3, 1)}


def map_figures(room, *, every: int, resolution: float, max_frames: int | None, segmenter: str | None = None,
                keep: Path | None = None) -> dict:
    """``semmap run`` on the kitchen with the real default (or ``segmenter``); its floor-plane and table-top
    figures (the run folder kept in ``keep`` when given)."""
    from semmap.config import InputConfig, MappingConfig, OutputConfig, RunConfig, SemanticsConfig
    from semmap.runner import run_config

    with tempfile.TemporaryDirectory() as tmp:
        out = keep or Path(tmp) / "kitchen"
        semantics = SemanticsConfig() if segmenter is None else SemanticsConfig(segmenter=segmenter, backend="onnx")
        config = RunConfig(input=InputConfig(dataset=KITCHEN, stride=every, max_frames=max_frames),
                           mapping=MappingConfig(resolution=resolution), semantics=semantics,
                           output=OutputConfig(out=out))
        t0 = time.perf_counter()
        result = run_config(config)
        seconds = time.perf_counter() - t0
        figures = cloud_figures(result.maps[0], room, resolution)
    return {"resolution": resolution, "frames": int(600 // every if max_frames is None else max_frames),
            "seconds": round(seconds, 1), "semantics": result.report.get("semantics"), **figures}


def cloud_figures(semantic_map, room, resolution: float) -> dict:
    """The floor-plane and table-top figures of a map (its classes read as semmap's names)."""
    cloud = semantic_map.cloud()
    fold, _ = fold_to(semantic_map.label_set)
    names = np.array([*INDOOR_LABELS.names, "-"])
    ids = np.where(cloud.labels < len(fold), fold[np.minimum(cloud.labels, len(fold) - 1)], len(INDOOR_LABELS))
    labels = names[ids]
    band = resolution * np.sqrt(3) / 2 + ON_PLANE_M
    on_floor = np.abs(room.floor.distance(cloud.centers)) < band
    is_floor = labels == "floor"
    out = {"voxels": len(cloud), "floor_plane_voxels": int(on_floor.sum()),
           "floor_plane_labelled_floor": round(float(np.mean(is_floor[on_floor])), 4) if on_floor.any() else None,
           "floor_voxels": int(is_floor.sum()),
           "floor_voxels_on_plane": round(float(np.mean(on_floor[is_floor])), 4) if is_floor.any() else None}
    if room.table is not None:
        on_table = np.abs(room.table.distance(cloud.centers)) < band
        is_table = labels == "table"
        out.update(table_voxels=int(is_table.sum()),
                   table_precision=round(float(np.mean(on_table[is_table])), 4) if is_table.any() else None,
                   table_off_floor=round(float(np.mean(~on_floor[is_table])), 4) if is_table.any() else None,
                   table_top_labelled_table=round(float(np.mean(is_table[on_table])), 4) if on_table.any() else None)
    kinds, counts = np.unique(labels, return_counts=True)
    out["largest_classes"] = {str(k): int(c) for k, c in sorted(zip(kinds, counts, strict=True),
                                                                key=lambda kc: -kc[1])[:8]}
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="every 30th frame, no networks but espnetv2")
    parser.add_argument("--segmenters", default=None, help="comma-separated (default: " +
                        ",".join(DEFAULT_SEGMENTERS) + ")")
    parser.add_argument("--no-map", action="store_true", help="skip the map of the kitchen")
    parser.add_argument("--every", type=int, default=None, help="yardstick frames: every N-th (default 10)")
    parser.add_argument("--map-every", type=int, default=None, help="map frames: every N-th (default 5)")
    parser.add_argument("--map-segmenter", default=None, help="map with this segmenter (default: the real default)")
    parser.add_argument("--keep", type=Path, default=None, help="keep the map's run folder here")
    args = parser.parse_args()
    if not KITCHEN.is_dir():
        raise SystemExit(f"the real-frame benchmark needs the 7-Scenes frames: {KITCHEN} not found")
    every = args.every or (30 if args.quick else 10)
    frames = list(open_dataset(KITCHEN, "7scenes", stride=every))
    room = fit_room(frames)
    yard = [label_frame(f, room) for f in frames]
    shares = np.bincount(np.concatenate([y.ravel() for y in yard]), minlength=5) / sum(y.size for y in yard)
    print(f"yardstick: {len(frames)} frames, up {np.round(room.up, 3).tolist()}, {len(room.walls)} walls, "
          f"floor {'found' if room.floor else 'none'}, ceiling {'found' if room.ceiling else 'none'}; pixels: wall "
          f"{shares[WALL_ID]:.1%}, floor {shares[FLOOR_ID]:.1%}, ceiling {shares[CEILING_ID]:.1%}, other "
          f"{shares[OTHER_ID]:.1%}, no depth {shares[0]:.1%}")
    names = (args.segmenters.split(",") if args.segmenters else
             ("structure", "espnetv2+structure") if args.quick else DEFAULT_SEGMENTERS)
    results = [score("structure", frames, yard, posed=False)] if "structure" in names else []
    for name in names:
        results.append(score(name, frames, yard))
    for r in results:
        print(f"{r['segmenter']:32s} wall {r['wall']}  floor {r['floor']}  ceiling {r['ceiling']}  "
              f"{r['ms_per_frame']} ms/frame")
    figures = None
    if not args.no_map:
        figures = map_figures(room, every=args.map_every or (15 if args.quick else 5), resolution=0.05,
                              max_frames=None, segmenter=args.map_segmenter, keep=args.keep)
        print("map:", json.dumps(figures))
    print(json.dumps({"bench": "real", "yardstick": {**room.to_dict(), "frames_every": every,
                                                     "pixel_shares": [round(float(s), 4) for s in shares]},
                      "results": results, "map": figures}))


if __name__ == "__main__":
    main()
