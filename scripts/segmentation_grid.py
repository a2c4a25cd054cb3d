"""Render a grid of real frames beside their predicted class masks, and summarise what the segmenter found.

For each chosen frame: the image, and the image with every pixel of a real class (not background / unknown)
tinted in its class colour and each class named at its largest region.  Prints, per class, its share of all
pixels, the mean confidence (top-1 probability) on its pixels and the frames it appears in; writes the grid PNG
and the same summary as JSON beside it.

    .venv/bin/python scripts/segmentation_grid.py [--dataset ../shared/data/7scenes-redkitchen] [--frames 0 100 ...]
        [--segmenter espnetv2 --weights ../shared/weights/espnetv2/espnetv2_s_2.0_pascal_384x384.pth]
        [--out docs/images/espnetv2_7scenes.png]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import cv2
import numpy as np

from semmap.datasets import open_dataset
from semmap.files.atomic import write_text_atomic
from semmap.perception.network import parse_input_size
from semmap.perception.registry import make_segmenter
from semmap.viz.preview import write_png

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared"
DEFAULT_FRAMES = (0, 100, 200, 300, 400, 500)
TINT = 0.55  # weight of the class colour over the image


def overlay(rgb: np.ndarray, labels: np.ndarray, names: tuple[str, ...], colors: np.ndarray) -> np.ndarray:
    """``rgb`` with real classes tinted and named at the centre of their largest connected region."""
    out = rgb.astype(np.float32)
    real = labels > 0
    out[real] = (1 - TINT) * out[real] + TINT * colors[labels[real]].astype(np.float32)
    out = out.astype(np.uint8)
    for c in np.unique(labels[real]):
        _, _, stats, centroids = cv2.connectedComponentsWithStats((labels == c).astype(np.uint8))
        biggest = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
        x, y = (int(v) for v in centroids[biggest])
        for color, width in (((0, 0, 0), 4), ((255, 255, 255), 1)):
            cv2.putText(out, names[c], (max(0, x - 30), y), cv2.FONT_HERSHEY_SIMPLEX, 0.6, color, width, cv2.LINE_AA)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--dataset", type=Path, default=SHARED / "data" / "7scenes-redkitchen")
    parser.add_argument("--frames", type=int, nargs="+", default=list(DEFAULT_FRAMES), help="frame indices")
    parser.add_argument("--segmenter", default="espnetv2")
    parser.add_argument("--weights", type=Path,
                        default=SHARED / "weights" / "espnetv2" / "espnetv2_s_2.0_pascal_384x384.pth")
    parser.add_argument("--input-size", type=parse_input_size, default=None,
                        help="network input: short side N or WxH (default: the segmenter's)")
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "images" / "espnetv2_7scenes.png")
    args = parser.parse_args()

    seg = make_segmenter(args.segmenter, weights=args.weights, input_size=args.input_size)
    names, colors = seg.label_set.names, seg.label_set.colors
    wanted = set(args.frames)
    rows, pixels, conf_sum, seen_in = [], np.zeros(len(names)), np.zeros(len(names)), {}
    for i, frame in enumerate(open_dataset(args.dataset)):
        if i not in wanted:
            continue
        # a network sees the colour camera's whole view (7-Scenes colour is registered onto depth for mapping)
        view = frame.raw_color.image if frame.raw_color is not None and hasattr(seg, "predict") else frame.rgb
        top = seg.predict(view) if view is not frame.rgb else seg.segment(frame)
        labels, conf = top.labels[..., 0].astype(np.int64), top.probs[..., 0]
        pixels += np.bincount(labels.ravel(), minlength=len(names))
        conf_sum += np.bincount(labels.ravel(), weights=conf.ravel(), minlength=len(names))
        found = [names[c] for c in np.unique(labels) if c > 0]
        for name in found:
            seen_in.setdefault(name, []).append(frame.name)
        print(f"{frame.name}: " + ", ".join(f"{names[c]} {100 * np.mean(labels == c):.1f}%"
                                            for c in np.unique(labels)))
        rows.append(np.hstack([view, overlay(view, labels, names, colors)]))
    if not rows:
        raise SystemExit(f"none of frames {sorted(wanted)} exists in {args.dataset}")
    total = pixels.sum()
    summary = {"segmenter": seg.name, "weights": str(args.weights), "frames": len(rows), "classes": {
        names[c]: {"pixel_share": round(float(pixels[c] / total), 4),
                   "mean_confidence": round(float(conf_sum[c] / pixels[c]), 3), "frames": seen_in.get(names[c], [])}
        for c in np.argsort(-pixels) if pixels[c] > 0}}
    print(f"\n{'class':14s} {'pixels':>8s} {'mean conf':>10s}  frames")
    for name, d in summary["classes"].items():
        print(f"{name:14s} {100 * d['pixel_share']:7.2f}% {d['mean_confidence']:10.3f}  {len(d['frames'])}")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    grid = np.vstack(rows)
    write_png(args.out, cv2.resize(grid, (grid.shape[1] // 2, grid.shape[0] // 2), interpolation=cv2.INTER_AREA))
    write_text_atomic(args.out.with_suffix(".json"), json.dumps(summary, indent=2))
    print(f"wrote {args.out} and {args.out.with_suffix('.json')}")


if __name__ == "__main__":
    main()
