"""Fit the 7-Scenes colour camera against the depth camera (the dataset gives only the depth camera: f = 585 px).

The Kinect's colour and depth images come from two cameras. Depth discontinuities (the near side of a jump)
are object outlines, and so are colour edges; this script finds the colour intrinsics (fx = fy, cx, cy) and the
offset of the colour camera (tx, ty) that put the outlines measured in depth onto the edges in colour, by
minimising the mean distance from each projected depth outline pixel to the nearest colour edge (Canny, capped
at 8 px) over frames spread through the sequence. The result is semmap's ``SEVEN_SCENES_COLOR_CAMERA``.

    .venv/bin/python scripts/calibrate_7scenes_color.py [../shared/data/7scenes-redkitchen] [--every 15]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from scipy.optimize import minimize

from semmap.datasets import open_dataset
from semmap.datasets.sevenscenes import SEVEN_SCENES_COLOR_CAMERA
from semmap.eval.registration import depth_outlines, edge_distance, sample

SHARED = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "7scenes-redkitchen"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("dataset", nargs="?", type=Path, default=SHARED)
    ap.add_argument("--every", type=int, default=15, help="use every k-th frame")
    args = ap.parse_args()
    data = []
    cam = None
    for frame in open_dataset(args.dataset, "7scenes", stride=args.every, raw_color=True):
        cam = frame.intrinsics
        data.append((*depth_outlines(frame.depth), edge_distance(frame.rgb)))
    if cam is None:
        raise SystemExit(f"{args.dataset}: no frames")

    def cost(p: np.ndarray) -> float:
        f, cx, cy, tx, ty = p
        total, count = 0.0, 0
        for u, v, z, dist in data:
            x = f * ((u - cam.cx) / cam.fx * z + tx) / z + cx
            y = f * ((v - cam.cy) / cam.fy * z + ty) / z + cy
            inside = (x >= 0) & (x < cam.width - 1) & (y >= 0) & (y < cam.height - 1)
            total += float(sample(dist, x[inside], y[inside]).sum())
            count += int(inside.sum())
        return total / max(count, 1)

    identity = np.array([cam.fx, cam.cx, cam.cy, 0.0, 0.0])
    best = None
    for start in (identity, np.array([525.0, cam.cx, cam.cy, 0.0, 0.0])):
        res = minimize(cost, start, method="Nelder-Mead", options={"xatol": 1e-4, "fatol": 1e-5, "maxiter": 3000})
        if best is None or res.fun < best.fun:
            best = res
    f, cx, cy, tx, ty = best.x
    c = SEVEN_SCENES_COLOR_CAMERA
    semmap_constants = np.array([c.fx, c.cx, c.cy, *c.t_color_depth[:2]])
    print(json.dumps({
        "frames": len(data), "outline_pixels": int(sum(len(d[0]) for d in data)),
        "fitted": {"f": round(f, 2), "cx": round(cx, 2), "cy": round(cy, 2), "tx_m": round(tx, 4),
                   "ty_m": round(ty, 4)},
        "mean_edge_distance_px": {"depth_camera_as_colour_camera": round(cost(identity), 3),
                                  "fitted": round(best.fun, 3),
                                  "semmap_constants": round(cost(semmap_constants), 3)},
    }, indent=1))


if __name__ == "__main__":
    from semmap.cli.terminal import exit_on_errors

    exit_on_errors(main, "calibrate_7scenes_color")  # a bad file or option: one line, not a traceback
