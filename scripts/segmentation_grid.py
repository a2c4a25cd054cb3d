"""Render real frames beside the class masks of one or more segmenters, and measure what each found, without
ground truth.

For each chosen frame: the image, then per segmenter the image with every pixel of a real class (not background /
unknown) tinted in its class colour and each class named at its largest region.  Written beside the PNG as JSON
(and printed), per segmenter and class: its share of all pixels, the mean confidence (top-1 probability) on its
pixels, the frames it appears in, and where its pixels lie in the scene's geometry -- on the floor, on raised
horizontal surfaces (0.4-1.2 m above the floor: table tops, counters, seats), on vertical surfaces (walls, cabinet
fronts) -- from the depth images and poses, with the up direction and the floor's height estimated from the frames'
surface normals.  Between the first segmenter and each other one: the IoU of matching classes (PASCAL VOC chair
and chair, diningtable and table/desk, ...).  That tells what a network trained elsewhere recognises here: a floor
label that lies on the floor, a table label on table-height surfaces, two networks that agree on the chairs.

    .venv/bin/python scripts/segmentation_grid.py [--dataset ../shared/data/7scenes-redkitchen] [--frames 0 100 ...]
        [--segmenter espnetv2 --weights ../shared/weights/espnetv2/espnetv2_s_2.0_pascal_384x384.pth]
        [--compare pspnet ...] [--out docs/images/networks_7scenes.png]
"""

from __future__ import annotations

import argparse
import itertools
import json
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from semmap.datasets import open_dataset
from semmap.files.atomic import write_text_atomic
from semmap.geometry import backproject, onto_depth_grid, pixel_normals
from semmap.perception.network import parse_input_size
from semmap.perception.registry import demo_network, make_segmenter
from semmap.viz.preview import write_png

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared"
DEFAULT_FRAMES = (0, 100, 200, 300, 400, 500)
TINT = 0.55  # weight of the class colour over the image
TILE_SCALE = 0.375  # each picture of the grid at this fraction of the frame's size (keeps the PNG under 1.5 MB)
GEOMETRY_STRIDE = 4  # depth pixels sampled for the geometric placement (every 4th row and column)
HORIZONTAL, VERTICAL = 0.95, 0.3  # |normal . up| above: horizontal surface; below: vertical surface
FLOOR_BAND = 0.10  # metres either side of the floor's height
RAISED = (0.4, 1.2)  # metres above the floor: table tops, counters, seats
#: Classes of two label sets that name the same thing (PASCAL VOC -> semmap's indoor classes).
SAME_THING = {"chair": ("chair",), "diningtable": ("table", "desk"), "tvmonitor": ("monitor",),
              "bottle": ("bottle",), "sofa": ("sofa",), "pottedplant": ("plant",), "person": ("person",)}
PLACES = ("floor", "raised", "vertical")
MIN_NAMED = 0.01  # a class is named in the picture where its largest region covers this share of the image


@dataclass
class Tally:
    """What one segmenter found over the frames: pixels, summed confidence and geometric placement per class."""

    names: tuple[str, ...]
    pixels: np.ndarray = field(init=False)
    conf_sum: np.ndarray = field(init=False)
    placed: np.ndarray = field(init=False)  # (K, 4): floor, raised, vertical, any valid normal
    seen_in: dict[str, list[str]] = field(default_factory=dict)

    def __post_init__(self) -> None:
        k = len(self.names)
        self.pixels, self.conf_sum, self.placed = np.zeros(k), np.zeros(k), np.zeros((k, len(PLACES) + 1))


def up_and_floor(frames: list) -> tuple[np.ndarray, float]:
    """The scene's up direction (mean normal of the surfaces facing the cameras' mean up, refined three times) and
    the floor's height along it (2nd percentile of the horizontal surfaces' heights)."""
    points, normals = zip(*(world_points_normals(f)[:2] for f in frames), strict=True)
    p, n = np.vstack(points), np.vstack(normals)
    up = -np.mean([f.T_world_cam[:3, 1] for f in frames], axis=0)  # cameras are held roughly upright
    for _ in range(3):
        up = n[n @ (up / np.linalg.norm(up)) > 0.8].mean(axis=0)
    up /= np.linalg.norm(up)
    return up, float(np.percentile(p[n @ up > HORIZONTAL] @ up, 2))


def world_points_normals(frame) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """World points, unit normals and flat depth-pixel indices of every GEOMETRY_STRIDE-th valid depth pixel
    with a normal."""
    pts, pix = backproject(frame.depth, frame.intrinsics, stride=GEOMETRY_STRIDE)
    T = frame.T_world_cam
    normals = pixel_normals(frame.depth, frame.intrinsics, T, pix)
    ok = np.linalg.norm(normals, axis=1) > 0.5
    return pts[ok] @ T[:3, :3].T + T[:3, 3], normals[ok], pix[ok]


def places(frame, up: np.ndarray, floor: float) -> tuple[np.ndarray, np.ndarray]:
    """Flat depth-pixel indices and, per pixel, which of PLACES it lies on (-1: none of them)."""
    p, n, pix = world_points_normals(frame)
    height, facing = p @ up - floor, n @ up
    where = np.full(len(pix), -1)
    where[np.abs(facing) < VERTICAL] = 2
    where[(facing > HORIZONTAL) & (height > RAISED[0]) & (height < RAISED[1])] = 1
    where[(facing > HORIZONTAL) & (np.abs(height) < FLOOR_BAND)] = 0
    return pix, where


def overlay(rgb: np.ndarray, labels: np.ndarray, names: tuple[str, ...], colors: np.ndarray) -> np.ndarray:
    """``rgb`` with real classes tinted, scaled by TILE_SCALE, each class named at the centre of its largest
    connected region (when that covers MIN_NAMED of the image)."""
    out = rgb.astype(np.float32)
    real = labels > 0
    out[real] = (1 - TINT) * out[real] + TINT * colors[labels[real]].astype(np.float32)
    out = shrink(out.astype(np.uint8))
    for c in np.unique(labels[real]):
        _, _, stats, centroids = cv2.connectedComponentsWithStats((labels == c).astype(np.uint8))
        biggest = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
        if stats[biggest, cv2.CC_STAT_AREA] < MIN_NAMED * labels.size:
            continue
        x, y = (int(v * TILE_SCALE) for v in centroids[biggest])
        for color, width in (((0, 0, 0), 3), ((255, 255, 255), 1)):
            cv2.putText(out, names[c], (max(0, x - 20), y), cv2.FONT_HERSHEY_SIMPLEX, 0.4, color, width, cv2.LINE_AA)
    return out


def shrink(image: np.ndarray) -> np.ndarray:
    """``image`` at TILE_SCALE of its size."""
    h, w = image.shape[:2]
    return cv2.resize(image, (round(w * TILE_SCALE), round(h * TILE_SCALE)), interpolation=cv2.INTER_AREA)


def count(tally: Tally, frame, labels: np.ndarray, conf: np.ndarray, up: np.ndarray, floor: float) -> None:
    """Add one frame's prediction (on the colour camera's view) to ``tally``."""
    k = len(tally.names)
    tally.pixels += np.bincount(labels.ravel(), minlength=k)
    tally.conf_sum += np.bincount(labels.ravel(), weights=conf.ravel(), minlength=k)
    for c in np.unique(labels):
        if c > 0:
            tally.seen_in.setdefault(tally.names[c], []).append(frame.name)
    (on_depth,) = onto_depth_grid(frame, labels.astype(np.int32))
    pix, where = places(frame, up, floor)
    lab = on_depth.ravel()[pix]
    for i in range(len(PLACES)):
        tally.placed[:, i] += np.bincount(lab[where == i], minlength=k)
    tally.placed[:, -1] += np.bincount(lab, minlength=k)


def agreement(a: np.ndarray, b: np.ndarray, names_a: tuple[str, ...], names_b: tuple[str, ...]) -> np.ndarray:
    """(pairs, 3) intersection, pixels of a, pixels of b for every SAME_THING pair of the two label sets."""
    rows = []
    for name_a, names in SAME_THING.items():
        ids_b = [names_b.index(n) for n in names if n in names_b]
        if name_a in names_a and ids_b:
            in_a, in_b = a == names_a.index(name_a), np.isin(b, ids_b)
            rows.append((np.sum(in_a & in_b), np.sum(in_a), np.sum(in_b)))
    return np.array(rows, np.float64).reshape(-1, 3)


def pairs(names_a: tuple[str, ...], names_b: tuple[str, ...]) -> list[str]:
    """The SAME_THING pairs :func:`agreement` counts, as ``a ~ b1/b2``."""
    return [f"{a} ~ {'/'.join(n for n in names if n in names_b)}" for a, names in SAME_THING.items()
            if a in names_a and any(n in names_b for n in names)]


def summarise(seg, weights: Path | None, tally: Tally) -> dict:
    """One segmenter's JSON summary: per class (most pixels first) share, confidence, frames and placement."""
    total = tally.pixels.sum()
    classes = {}
    for c in np.argsort(-tally.pixels):
        if tally.pixels[c] == 0:
            continue
        placed = tally.placed[c]
        classes[tally.names[c]] = {
            "pixel_share": round(float(tally.pixels[c] / total), 4),
            "mean_confidence": round(float(tally.conf_sum[c] / tally.pixels[c]), 3),
            "frames": tally.seen_in.get(tally.names[c], []),
            "on": {p: round(float(placed[i] / placed[-1]), 3) if placed[-1] else None for i, p in enumerate(PLACES)}}
    on_place = {}
    for i, p in enumerate(PLACES):
        col = tally.placed[:, i]
        top = np.argsort(-col)[:3]
        on_place[p] = {tally.names[c]: round(float(col[c] / col.sum()), 3) for c in top if col[c] > 0}
    return {"segmenter": seg.name, "weights": None if weights is None else str(weights), "classes": classes,
            "labels_on": on_place}


def print_summary(s: dict) -> None:
    """The table of one segmenter's summary."""
    print(f"\n{s['segmenter']}\n{'class':14s} {'pixels':>8s} {'mean conf':>10s} {'frames':>6s}  "
          + "  ".join(f"on {p:8s}" for p in PLACES))
    for name, d in s["classes"].items():
        on = "  ".join(f"{'-' if v is None else f'{100 * v:.0f}%':>11s}" for v in d["on"].values())
        print(f"{name:14s} {100 * d['pixel_share']:7.2f}% {d['mean_confidence']:10.3f} {len(d['frames']):6d}  {on}")
    for p, top in s["labels_on"].items():
        print(f"  the {p} pixels are labelled " + ", ".join(f"{n} {100 * v:.0f}%" for n, v in top.items()))


def parse_args() -> argparse.Namespace:
    """Command line."""
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--dataset", type=Path, default=SHARED / "data" / "7scenes-redkitchen")
    parser.add_argument("--frames", type=int, nargs="+", default=list(DEFAULT_FRAMES), help="frame indices")
    parser.add_argument("--segmenter", default="espnetv2")
    parser.add_argument("--weights", type=Path,
                        default=ROOT / "weights" / "espnetv2" / "espnetv2_s_2.0_pascal_384x384.pth")
    parser.add_argument("--compare", nargs="*", default=None,
                        help="further segmenters in their own columns, with their default (shipped) weights "
                             "(default: the demo's network; --compare alone: none)")
    parser.add_argument("--input-size", type=parse_input_size, default=None,
                        help="network input of --segmenter: short side N or WxH (default: the segmenter's)")
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "images" / "networks_7scenes.png")
    return parser.parse_args()


def main() -> None:
    args = parse_args()
    compare = [demo_network() or "pspnet"] if args.compare is None else args.compare
    segs = [make_segmenter(args.segmenter, weights=args.weights, input_size=args.input_size),
            *(make_segmenter(name) for name in compare)]
    wanted = set(args.frames)
    frames = [f for i, f in enumerate(itertools.islice(open_dataset(args.dataset, raw_color=False), max(wanted) + 1))
              if i in wanted]
    if not frames:
        raise SystemExit(f"none of frames {sorted(wanted)} exists in {args.dataset}")
    up, floor = up_and_floor(frames)
    tallies = [Tally(s.label_set.names) for s in segs]
    agree = [np.zeros((len(pairs(segs[0].label_set.names, s.label_set.names)), 3)) for s in segs[1:]]
    rows = []
    # a segmenter that needs depth (structure, NAME+structure) sees the frame as semmap run gives it, colour
    # registered onto depth, and so do the others beside it; else each sees the colour camera's whole view
    framed = any(not hasattr(seg, "predict") for seg in segs)
    for frame in frames:
        framed_view = frame.rgb if framed or frame.raw_color is None else None
        view = framed_view if framed_view is not None else frame.raw_color.image
        tops = [seg.segment(frame) if framed else seg.predict(view) for seg in segs]
        labels = [t.labels[..., 0].astype(np.int64) for t in tops]
        for top, lab, tally in zip(tops, labels, tallies, strict=True):
            count(tally, frame, lab, top.probs[..., 0], up, floor)
        for i, seg in enumerate(segs[1:]):
            agree[i] += agreement(labels[0], labels[i + 1], segs[0].label_set.names, seg.label_set.names)
        rows.append(np.hstack([shrink(view), *(overlay(view, lab, s.label_set.names, s.label_set.colors)
                                               for s, lab in zip(segs, labels, strict=True))]))
        print(f"{frame.name} done")
    summary = {"frames": [f.name for f in frames], "up": [round(float(v), 3) for v in up],
               "floor_height": round(floor, 3),
               "depth_pixels_on": {p: round(float(tallies[0].placed[:, i].sum() / tallies[0].placed[:, -1].sum()), 3)
                                   for i, p in enumerate(PLACES)}, "segmenters": [
                   summarise(s, args.weights if i == 0 else None, t)
                   for i, (s, t) in enumerate(zip(segs, tallies, strict=True))], "agreement": {
                   f"{segs[0].name} vs {s.name}": {
                       pair: {"iou": round(float(a[0] / max(a[1] + a[2] - a[0], 1)), 3),
                              f"share_of_{segs[0].name}": round(float(a[0] / max(a[1], 1)), 3),
                              f"share_of_{s.name}": round(float(a[0] / max(a[2], 1)), 3)}
                       for pair, a in zip(pairs(segs[0].label_set.names, s.label_set.names), agree[i], strict=True)}
                   for i, s in enumerate(segs[1:])}}
    print(f"up {summary['up']}, floor at {floor:.2f} m; depth pixels on " +
          ", ".join(f"{p} {100 * v:.0f}%" for p, v in summary["depth_pixels_on"].items()))
    for s in summary["segmenters"]:
        print_summary(s)
    print(json.dumps(summary["agreement"], indent=1))
    size = write_png(args.out, np.vstack(rows))
    write_text_atomic(args.out.with_suffix(".json"), json.dumps(summary, indent=2))
    print(f"wrote {args.out} ({size / 1e6:.2f} MB) and {args.out.with_suffix('.json')}")


if __name__ == "__main__":
    from semmap.cli.terminal import exit_on_errors

    exit_on_errors(main, "segmentation_grid")  # a bad file or option: one line, not a traceback
