"""Segmentation speed on the CPU: ESPNetv2 (s=1.0, s=2.0) per 640x480 frame at 384 px, PyTorch vs ONNX Runtime.

Inputs: 384x384 (the weights' training size), 512x384 (384 px short side keeping the aspect ratio) and
432x320 (semmap's default, 320 px short side). A frame's time covers everything `semmap run` pays: resize and
normalise, the network, softmax, bilinear sampling of the probabilities at 640x480 and top-3.  The network alone
is reported too.  Frames are the real 7-Scenes images in ../shared (random images when absent).  The last line is JSON:
{"bench": "segmenters", "results": [{"model": "espnetv2-s2.0", "backend": "torch", "ms_per_frame": ...}, ...]}

    python benchmarks/bench_segmenters.py [--quick] [--threads 2] [--inputs 384x384,384,320]
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

import numpy as np

from semmap.datasets.base import read_color
from semmap.perception.network import parse_input_size
from semmap.perception.registry import make_segmenter

SHARED = Path(__file__).resolve().parents[1].parent / "shared"
WEIGHTS = SHARED / "weights" / "espnetv2"
FRAMES = SHARED / "data" / "7scenes-redkitchen"


def _images(n: int) -> list[np.ndarray]:
    paths = sorted(FRAMES.glob("frame-*.color.*"))[:: 600 // n][:n] if FRAMES.is_dir() else []
    if paths:
        return [read_color(p) for p in paths]
    rng = np.random.default_rng(0)
    return [rng.integers(0, 256, (480, 640, 3), dtype=np.uint8) for _ in range(n)]


def _median_ms(fn, items, repeats: int) -> float:
    fn(items[0])  # warm-up (ONNX Runtime and oneDNN pick kernels on first use)
    times = []
    for _ in range(repeats):
        for item in items:
            t0 = time.perf_counter()
            fn(item)
            times.append((time.perf_counter() - t0) * 1e3)
    return statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="fewer frames")
    parser.add_argument("--threads", type=int, default=2, help="CPU threads for both runtimes")
    parser.add_argument("--inputs", default="384x384,384,320",
                        help="network inputs, comma separated: WxH or short side")
    args = parser.parse_args()
    images = _images(4 if args.quick else 12)
    repeats = 1 if args.quick else 2
    results = []
    for s in ("1.0", "2.0"):
        weights = WEIGHTS / f"espnetv2_s_{s}_pascal_384x384.pth"
        if not weights.is_file():
            print(f"skipping espnetv2-s{s}: {weights} not found")
            continue
        for size, backend in ((size, b) for size in args.inputs.split(",") for b in ("torch", "onnx")):
            seg = make_segmenter("espnetv2", weights=weights, backend=backend, threads=args.threads,
                                 input_size=parse_input_size(size))
            frame_ms = _median_ms(seg.predict, images, repeats)
            x = images[0]
            net_ms = _median_ms(lambda img, seg=seg: seg.logits([img]), [x] * len(images), repeats)
            results.append({"model": f"espnetv2-s{s}", "backend": backend, "ms_per_frame": round(frame_ms, 1),
                            "network_ms": round(net_ms, 1),
                            "input": "x".join(map(str, seg.net_input.size_for(640, 480))), "frame": "640x480",
                            "threads": args.threads})
            print(f"espnetv2 s={s} {results[-1]['input']:>7s} {backend:5s}: {frame_ms:6.1f} ms/frame "
                  f"(network {net_ms:6.1f} ms)")
    by = {(r["model"], r["input"], r["backend"]): r["ms_per_frame"] for r in results}
    for (model, size, backend), ms in by.items():
        if backend == "onnx" and (model, size, "torch") in by:
            print(f"{model} {size}: ONNX Runtime is x{by[(model, size, 'torch')] / ms:.2f} the speed of PyTorch")
    print(json.dumps({"bench": "segmenters", "results": results}))


if __name__ == "__main__":
    main()
