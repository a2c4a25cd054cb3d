"""Picture of a run's object map: the semantic OctoMap from above, dimmed, and every object on it in its own colour
with its upright box and ``id class`` label where it overprints no other (what ``docs/images/objects_7scenes.png``
shows, with the count per class in its title). From the checkout's root; ``../shared/data/7scenes-redkitchen`` is
the shared 7-Scenes copy beside it (substitute your own sequence, docs/FIRST_STEPS.md); the real default
(espnetv2+structure), ground-truth poses, every 5th frame:

    .venv/bin/semmap run ../shared/data/7scenes-redkitchen --out OUT --stride 5 --poses gt --instances components
    .venv/bin/python scripts/objects_picture.py OUT --out docs/images/objects_7scenes.png [--classes chair,diningtable]

Also prints, per class, how many objects the map holds and, for the class named by ``--near``, how far each of its
objects lies from the nearest object of the ``--near-to`` class (chairs around the table).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from semmap.io.native import load_map
from semmap.io.objects import object_colors, read_objects_json, read_objects_ply
from semmap.maps.objects import MapObject
from semmap.viz.objects import objects_top_down
from semmap.viz.preview import side_by_side, write_png


def _objects(run: Path) -> tuple[list[MapObject], dict[str, int], np.ndarray]:
    """The run's objects rebuilt from objects.json / objects.ply (enough to draw), class ids by name, and up."""
    records = read_objects_json(run / "objects.json")
    up = np.asarray(json.loads((run / "objects.json").read_text())["up"], np.float64)
    ply = read_objects_ply(run / "objects.ply")
    out, names = [], {}
    for r in records:
        sel = ply["object"] == r["id"]
        o = MapObject(r["id"], np.zeros(1), np.zeros(0, np.int64), ply["points"][sel], ply["colors"][sel],
                      np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0, np.int64), class_id=r["class_id"])
        names[r["class"]] = r["class_id"]
        out.append(o)
    return out, names, up


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("run", type=Path, help="output folder of semmap run --instances ...")
    ap.add_argument("--out", type=Path, required=True, help="PNG to write")
    ap.add_argument("--classes", default="", help="draw only these classes (comma-separated; default all)")
    ap.add_argument("--near", default="chair", help="class whose distance to --near-to objects is printed")
    ap.add_argument("--near-to", default="diningtable")
    ap.add_argument("--size", type=int, default=640)
    args = ap.parse_args()
    objects, names, up = _objects(args.run)
    keep = {c for c in args.classes.split(",") if c}
    if keep:
        objects = [o for o in objects if any(names.get(c) == o.class_id for c in keep)]
    label_names = {cid: name for name, cid in names.items()}
    all_names = tuple(label_names.get(i, "") for i in range(max(label_names, default=0) + 1))
    m = load_map(args.run / "map.semmap")
    cloud = m.cloud()
    height = cloud.centers @ up
    background = (cloud.centers[height < np.percentile(height, 90)], cloud.colors[height < np.percentile(height, 90)])
    colors = object_colors(max([o.id for o in objects], default=0))
    image = objects_top_down(objects, colors, all_names, up=up, size=args.size, background=background)
    counts: dict[str, int] = {}
    for o in objects:
        counts[all_names[o.class_id]] = counts.get(all_names[o.class_id], 0) + 1
    per_class = ", ".join(f"{n} {c}" for n, c in sorted(counts.items(), key=lambda nc: (-nc[1], nc[0])))
    title = f"objects from above: {len(objects)}" + (f" ({per_class})" if per_class else "") + f", {args.run.name}"
    write_png(args.out, side_by_side([image], [title]))
    print(json.dumps({"objects": counts}))
    if args.near in names and args.near_to in names:
        near = [o for o in objects if o.class_id == names[args.near]]
        to = [o for o in objects if o.class_id == names[args.near_to]]
        for o in near:
            d = min((float(np.sqrt(((t.points[:, None, :] - o.points[None, ::7, :]) ** 2).sum(-1)).min())
                     for t in to), default=float("nan"))
            print(json.dumps({"object": o.id, "class": args.near, f"metres_to_{args.near_to}": round(d, 3)}))


if __name__ == "__main__":
    from semmap.cli.terminal import exit_on_errors

    exit_on_errors(main, "objects_picture")  # a bad file or option: one line, not a traceback
