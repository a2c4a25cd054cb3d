"""Segmentation cost on the CPU as `semmap run` pays it: ESPNetv2 (s=1.0, s=2.0), PyTorch vs ONNX Runtime.

Each configuration is built by the same factory call as a run (``make_segmenter``, the run's thread settings
unless ``--threads`` is given) and timed on what a run hands it: 7-Scenes frames from the dataset reader,
colour registered onto depth, segmented through ``NetworkSegmenter.segment`` (the colour camera's whole view
resized and normalised, the network, softmax, bilinear sampling at 640x480 and top-3, classes carried onto the
depth grid).  Reported per configuration, in the same run:

- ``ms_per_frame``: a frame through ``segment`` (what ``report.json``'s ``segment`` time holds per segmented
  frame), best of the repeats per frame, median over frames;
- ``network_ms``: the network alone on the same input (so ``ms_per_frame - network_ms`` is what the run adds);
- ``prepare_s``: the one-off start-up a run pays before its frame loop (``prepare``: PyTorch's first pass, or
  the ONNX export and session; ``prepare_cached_s``: opening the session from the export cache, what every later
  run pays).  Before the pooling weights became graph constants, the ONNX graph of ESPNetv2 had 72k nodes and
  opening it took about 30 s of CPU in every run, paid by the first segmented frame: spread over a 600-frame run
  segmenting every 5th frame, the 380 ms per segmented frame `semmap run` reported against 70-80 ms here.

Inputs: 384x384 (the weights' training size), 512x384 (384 px short side) and 432x320 (semmap's default, 320 px
short side).  Random frames stand in when ../shared is absent.  The last line is JSON:
{"bench": "segmenters", "results": [{"model": "espnetv2-s2.0", "backend": "onnx", "ms_per_frame": ...}, ...]}

    python benchmarks/bench_segmenters.py [--quick] [--threads N] [--inputs 384x384,384,320]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from semmap.perception.network import parse_input_size
from semmap.perception.registry import make_segmenter
from semmap.types import CameraIntrinsics, Frame

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
WEIGHTS = Path(__file__).resolve().parents[1] / "weights" / "espnetv2"
FRAMES = SHARED / "data" / "7scenes-redkitchen"


def _frames(n: int) -> tuple[str, list[Frame]]:
    """``n`` frames spread over the sequence, as the 7-Scenes reader gives them to a run."""
    if FRAMES.is_dir():
        from semmap.datasets import open_dataset

        return "7scenes-redkitchen", list(open_dataset(FRAMES, "7scenes", stride=600 // n, max_frames=n))
    rng = np.random.default_rng(0)
    cam = CameraIntrinsics(640, 480, 525.0, 525.0, 319.5, 239.5)
    return "random images", [Frame(i, i / 30, rng.integers(0, 256, (480, 640, 3), dtype=np.uint8),
                                   np.full((480, 640), 2.0, np.float32), cam) for i in range(n)]


def _median_best_ms(fn, items, repeats: int) -> float:
    """Each item's best time over ``repeats`` passes, median over the items (ms)."""
    best = [float("inf")] * len(items)
    for _ in range(repeats):
        for i, item in enumerate(items):
            t0 = time.perf_counter()
            fn(item)
            best[i] = min(best[i], (time.perf_counter() - t0) * 1e3)
    return statistics.median(best)


def _image(frame: Frame) -> np.ndarray:
    return frame.rgb if frame.raw_color is None else frame.raw_color.image


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="fewer frames and configurations")
    parser.add_argument("--threads", type=int, default=None, help="CPU threads for both runtimes (default: as a "
                        "run, the runtimes' own choice)")
    parser.add_argument("--inputs", default=None, help="network inputs, comma separated: WxH or short side "
                        "(default 384x384,384,320; quick 320)")
    args = parser.parse_args()
    source, frames = _frames(4 if args.quick else 12)
    repeats = 2 if args.quick else 3
    inputs = (args.inputs or ("320" if args.quick else "384x384,384,320")).split(",")
    results = []
    for s in ("2.0",) if args.quick else ("1.0", "2.0"):
        weights = WEIGHTS / f"espnetv2_s_{s}_pascal_384x384.pth"
        if not weights.is_file():
            print(f"skipping espnetv2-s{s}: {weights} not found")
            continue
        for size, backend in ((size, b) for size in inputs for b in ("torch", "onnx")):
            with tempfile.TemporaryDirectory() as cache:
                os.environ["SEMMAP_CACHE_DIR"] = cache  # a first run: the export is part of its start-up
                seg = make_segmenter("espnetv2", weights=weights, backend=backend, threads=args.threads,
                                     input_size=parse_input_size(size))
                prepare_s = seg.prepare(frames[0])
                cached_s = float("nan")
                if backend == "onnx":  # a later run opens the cached export
                    seg = make_segmenter("espnetv2", weights=weights, backend=backend, threads=args.threads,
                                         input_size=parse_input_size(size))
                    cached_s = seg.prepare(frames[0])
                frame_ms = _median_best_ms(seg.segment, frames, repeats)
                net_ms = _median_best_ms(lambda f, seg=seg: seg.logits([_image(f)]), frames, repeats)
                os.environ.pop("SEMMAP_CACHE_DIR")
            results.append({"model": f"espnetv2-s{s}", "backend": backend, "ms_per_frame": round(frame_ms, 1),
                            "network_ms": round(net_ms, 1), "prepare_s": round(prepare_s, 2),
                            "prepare_cached_s": None if cached_s != cached_s else round(cached_s, 2),
                            "input": "x".join(map(str, seg.net_input.size_for(640, 480))), "frame": "640x480",
                            "threads": args.threads, "frames": source})
            r = results[-1]
            print(f"espnetv2 s={s} {r['input']:>7s} {backend:5s}: {frame_ms:6.1f} ms/frame as a run pays it "
                  f"(network {net_ms:6.1f} ms, the rest {frame_ms - net_ms:5.1f}); start-up {prepare_s:.1f} s"
                  + (f" first run, {cached_s:.1f} s later runs" if backend == "onnx" else ""))
    by = {(r["model"], r["input"], r["backend"]): r["ms_per_frame"] for r in results}
    for (model, size, backend), ms in by.items():
        if backend == "onnx" and (model, size, "torch") in by:
            print(f"{model} {size}: ONNX Runtime is x{by[(model, size, 'torch')] / ms:.2f} the speed of PyTorch")
    print(json.dumps({"bench": "segmenters", "results": results}))


if __name__ == "__main__":
    main()
