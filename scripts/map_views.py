"""Render a class-coloured OctoMap file (``map.ot`` from ``semmap run``) from four sides, and count its voxels
per class colour.

The picture is made from the ``.ot`` file alone, read back with semmap's OctoMap reader, so it shows what
octovis or any other OctoMap tool would show. Voxels are counted per class by matching their colour to the
label set's palette (PASCAL VOC by default); grey voxels are background / unclassified (so a class whose
colour is itself grey, VOC's car, is not counted). The world's up
direction comes from ``trajectory.txt`` beside the map when present. Writes the PNG and prints JSON counts.

    .venv/bin/python scripts/map_views.py outputs/kitchen/map.ot [--out docs/images/kitchen_map.png] [--labels voc]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from semmap.io.octomap_files import read_octomap
from semmap.io.trajectory import read_trajectory
from semmap.keys import keys_to_coords
from semmap.viz.preview import CEILING_MARGIN, perspective, side_by_side, up_vector, write_png

AZIMUTHS = (0.0, 90.0, 180.0, 270.0)


def label_palette(name: str):
    if name == "voc":
        from semmap.perception.voc import PASCAL_VOC

        return PASCAL_VOC
    from semmap.labels import INDOOR_LABELS

    return INDOOR_LABELS


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("map", type=Path, help="a ColorOcTree .ot file")
    parser.add_argument("--out", type=Path, default=None, help="PNG to write (default: MAP_views.png)")
    parser.add_argument("--labels", choices=("voc", "indoor"), default="voc", help="palette to count classes by")
    parser.add_argument("--keep-high", action="store_true",
                        help="draw everything (by default voxels above the camera path are left out, like a ceiling)")
    args = parser.parse_args()
    leaves = read_octomap(args.map)
    if leaves.colors is None:
        raise SystemExit(f"{args.map}: not a ColorOcTree (.ot) file, it has no colours")
    occupied = leaves.occupied()
    keys, leaf_of = leaves.expand()
    keep = occupied[leaf_of]
    centers = keys_to_coords(keys[keep], leaves.resolution)
    colors = leaves.colors[leaf_of[keep]]
    traj_path = args.map.with_name("trajectory.txt")
    poses = read_trajectory(traj_path).poses if traj_path.is_file() else np.zeros((0, 4, 4))
    up = up_vector(poses)
    cut = float((poses[:, :3, 3] @ up).max() + CEILING_MARGIN) if len(poses) and not args.keep_high else None
    views = [perspective(centers, colors, leaves.resolution, up=up, max_height=cut, azimuth_deg=a, tilt_deg=35.0,
                         width=560, height=420) for a in AZIMUTHS]
    titles = [f"{args.map.name}, azimuth {a:.0f} deg" for a in AZIMUTHS]
    grid = np.concatenate([side_by_side(views[:2], titles[:2]), side_by_side(views[2:], titles[2:])], axis=0)
    out = args.out or args.map.with_name(args.map.stem + "_views.png")
    write_png(out, grid)
    labels = label_palette(args.labels)
    counts = {}
    for cid, (name, col) in enumerate(zip(labels.names, labels.colors, strict=True)):
        n = int(np.all(colors == col, axis=1).sum())
        if cid > 0 and n and not col[0] == col[1] == col[2]:  # a grey class colour (VOC car) is ambiguous
            counts[name] = n
    grey = int(((colors[:, 0] == colors[:, 1]) & (colors[:, 1] == colors[:, 2])).sum())
    print(json.dumps({"map": str(args.map), "occupied_voxels": len(colors), "grey_unclassified": grey,
                      "voxels_per_class_colour": counts, "image": str(out)}))


if __name__ == "__main__":
    from semmap.cli.terminal import exit_on_errors

    exit_on_errors(main, "map_views")  # a bad file or option: one line, not a traceback
