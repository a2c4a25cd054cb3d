"""A real network through ``--segmenter onnx:`` and a sidecar against semmap's own runner of the same network.

Exports ESPNetv2-PASCAL (``../shared/weights/espnetv2``) to ONNX at 7-Scenes' network input (432x320, logits at
half resolution, corner-aligned), writes the sidecar a user would write, and segments 7-Scenes frames with both the
built-in ``espnetv2`` segmenter and ``onnx:``; prints how often their top classes agree, their largest probability
difference and the milliseconds per frame of each. Everything is written to a temporary folder.

    PYTHONPATH=src python scripts/research/onnx_sidecar_check.py [--frames 6] [--s 2.0]
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np
import torch

from semmap.datasets import open_dataset
from semmap.perception.espnetv2 import IMAGENET_MEAN, IMAGENET_STD, load_espnetv2
from semmap.perception.registry import make_segmenter
from semmap.perception.voc import VOC_NAMES

SHARED = Path(__file__).resolve().parents[3] / "shared"


def main() -> None:
    """Export, segment with both, print the comparison as JSON."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=6)
    ap.add_argument("--s", default="2.0", choices=("1.0", "2.0"))
    args = ap.parse_args()
    weights = Path(__file__).resolve().parents[2] / "weights" / "espnetv2" / f"espnetv2_s_{args.s}_pascal_384x384.pth"
    frames = list(open_dataset(SHARED / "data" / "7scenes-redkitchen", "auto", stride=50, max_frames=args.frames))
    with tempfile.TemporaryDirectory() as tmp:
        model = Path(tmp) / "espnetv2.onnx"
        net = load_espnetv2(weights, full_resolution=False).eval()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            torch.onnx.export(net, (torch.zeros(1, 3, 320, 432),), str(model), input_names=["image"],
                              output_names=["logits"], opset_version=17, dynamo=False)
        model.with_suffix(".json").write_text(json.dumps({
            "input": {"size": [432, 320], "mean": list(IMAGENET_MEAN), "std": list(IMAGENET_STD)},
            "output": {"kind": "logits", "layout": "NCHW", "align_corners": True}, "labels": list(VOC_NAMES)}))
        native = make_segmenter("espnetv2", weights=weights, k=3)
        user = make_segmenter(f"onnx:{model}", k=3)
        native.segment(frames[0])
        user.segment(frames[0])
        agree, diff, ms = [], 0.0, {"espnetv2 (torch)": 0.0, "onnx: sidecar": 0.0}
        for f in frames:
            t0 = time.perf_counter()
            a = native.segment(f)
            t1 = time.perf_counter()
            b = user.segment(f)
            ms["espnetv2 (torch)"] += (t1 - t0) * 1e3 / len(frames)
            ms["onnx: sidecar"] += (time.perf_counter() - t1) * 1e3 / len(frames)
            agree.append(float((a.labels[..., 0] == b.labels[..., 0]).mean()))
            diff = max(diff, float(np.abs(a.probs - b.probs).max()))
    print(json.dumps({"frames": len(frames), "top_class_agreement_min": min(agree), "max_prob_diff": diff,
                      "ms_per_frame": {k: round(v, 1) for k, v in ms.items()}}, indent=2))


if __name__ == "__main__":
    main()
