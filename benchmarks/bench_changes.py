"""`semmap diff` against the simulator's ground truth (issue 36, deliverable 3): objects moved, removed and added
between two recordings of one simulated room are found with what precision and recall.

    python benchmarks/bench_changes.py [--quick] [--frames N] [--match-radius M] [--instance-errors exact] [--cache DIR]
        [--scenes office:4,kitchen:5,...]

For each scene (kind, seed) the room is recorded twice along the same loop (`semmap simulate`, 320x240, no noise,
30 frames spread over the loop by 1 fps): as it was, and after `--changes 3` (one move, one removal,
one addition). Both recordings are mapped as `semmap run SEQ --resolution 0.05 --instances oracle` maps them
(ground-truth poses, its objects.json) and compared as `semmap diff A B` compares them (``export_diff``). A true
change is found when the diff reports it with the same class and kind within ``TOLERANCE`` metres (xy) of its true
centroid(s): a move as "moved" from near its old place to near its new one, a removal as "disappeared" near its old
place, an addition as "appeared" near its new place. Precision is found changes over all object changes reported
(moved + appeared + disappeared), recall found over true.

Some changes no comparison of the two maps can find; :func:`observability` tells them from the simulator's true
boxes and the two maps alone (not from the diff): a removal needs the object seen in the first map and at least
half of its voxels observed by the second, an addition the reverse, a move both ends. Precision and recall are
printed over all changes and over the observable ones (reports at an unobservable change's places left out).
The last line is JSON: ``{"bench": "changes", "changes": N, "precision": P, "recall": R, "observable_changes": M,
"observable_precision": P', "observable_recall": R', "rows": [...]}``. ``--cache DIR`` keeps the recordings and
maps for the next run (the diff alone takes 1-3 s a room); ``--scenes`` measures other rooms.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

#: (kind, scene seed) of the rooms: small rooms with at least three objects that can change.
SCENES = (("office", 1), ("office", 2), ("office", 3), ("kitchen", 0), ("kitchen", 1), ("kitchen", 2),
          ("kitchen", 3))
#: How far (m, in xy) a reported object centroid may lie from the true one (the map's centroid is of the seen surface).
TOLERANCE = 0.5
#: The camera path of both recordings.
TRAJECTORY = "loop"  # round the room looking across it (an orbit looks inward and misses objects by the walls)
#: What each true change kind is reported as.
REPORTED_AS = {"move": "moved", "remove": "disappeared", "add": "appeared"}


def near(a, b) -> bool:
    """Whether two centroids lie within TOLERANCE of each other in xy."""
    return bool(np.linalg.norm(np.asarray(a, float)[:2] - np.asarray(b, float)[:2]) <= TOLERANCE)


def found(truth: dict, reported: dict) -> bool:
    """Whether the reported object change (a record of diff.json) is the true one (a record of changes.json)."""
    if reported["class"] != truth["class"]:
        return False
    if truth["change"] == "move":
        return near(reported["from"], truth["from"]) and near(reported["to"], truth["to"])
    return near(reported["at"], truth["from"] if truth["change"] == "remove" else truth["to"])


def score(truths: list[dict], changes: dict[str, list[dict]]) -> dict:
    """True changes found, reported changes that are true, and the misses and false reports by kind."""
    used: set[tuple[str, int]] = set()
    missed: list[str] = []
    for t in truths:
        kind = REPORTED_AS[t["change"]]
        hit = next((i for i, r in enumerate(changes[kind]) if (kind, i) not in used and found(t, r)), None)
        if hit is None:
            missed.append(f"{t['change']} {t['class']}")
        else:
            used.add((kind, hit))
    false = [f"{kind} {r['class']}" for kind in REPORTED_AS.values() for i, r in enumerate(changes[kind])
             if (kind, i) not in used]
    return {"true": len(truths), "found": len(truths) - len(missed), "reported": len(used) + len(false),
            "correct": len(used), "missed": missed, "false": false}


#: A map has seen an object where it holds at least this many voxels of its class inside its true box.
MIN_VOXELS = 5
#: ... and the other map observed a place when it saw (free or occupied) at least this share of those voxels.
MIN_OBSERVED = 0.5


def place_seen(vol_own, vol_other, obj, cls: str) -> tuple[int, float]:
    """Voxels of class ``cls`` that ``vol_own`` holds inside the true box of ``obj`` (a SceneObject), and the share
    of them that ``vol_other`` observed (free or occupied)."""
    from semmap.products.occupancy import FREE

    lo = np.maximum(vol_own.index_of(obj.bbox_min[None])[0], 0)
    hi = np.minimum(vol_own.index_of(obj.bbox_max[None])[0] + 1, vol_own.shape)
    if np.any(hi <= lo):
        return 0, 0.0
    box = tuple(slice(a, b) for a, b in zip(lo, hi, strict=True))
    names = list(vol_own.label_set.names)
    mine = (vol_own.state[box] == 1) & (vol_own.labels[box] == names.index(cls))
    return int(mine.sum()), float((vol_other.state[box][mine] >= FREE).mean()) if mine.any() else 0.0


def observability(truths: list[dict], kind: str, seed: int, changes: int, runs: list[Path]) -> list[str]:
    """Per true change, why no map comparison can find it ("" when it can): an end of it that the map holding the
    object did not see, or whose place the other map did not observe. A removal needs the object seen before and
    its place observed after; an addition the reverse; a move both (seen at both ends, each place observed by the
    other map: otherwise it is indistinguishable from an addition or a removal)."""
    from semmap.products.changes import _common_volumes
    from semmap.products.export import load_product_map
    from semmap.sim.changes import change_scene
    from semmap.sim.scene import generate_scene

    before = generate_scene(seed, kind, "small")
    after, _ = change_scene(before, changes, seed=seed + 1)
    va, vb = _common_volumes(load_product_map(runs[0])[0], load_product_map(runs[1])[0])
    objects = ({o.instance_id: o for o in before.objects}, {o.instance_id: o for o in after.objects})
    out = []
    for t in truths:
        ends = []
        if t["change"] in ("move", "remove"):
            ends.append(("old place", va, vb, objects[0][t["id"]]))
        if t["change"] in ("move", "add"):
            ends.append(("new place", vb, va, objects[1][t["new_id"] if t["change"] == "add" else t["id"]]))
        why = ""
        for name, own, other, obj in ends:
            n, share = place_seen(own, other, obj, t["class"])
            if n < MIN_VOXELS:
                why = f"{name}: object not seen ({n} voxels)"
            elif share < MIN_OBSERVED:
                why = f"{name}: {100 * share:.0f} % observed by the other walk"
        out.append(why)
    return out


def without(changes: dict[str, list[dict]], hidden: list[dict]) -> dict[str, list[dict]]:
    """The reported changes less those of an unobservable true change's class at one of its places (what the diff
    could see of it, e.g. the new place of a move whose old place the second walk never looked at)."""
    def at_hidden(r: dict) -> bool:
        places = [r[k] for k in ("at", "from", "to") if k in r]
        return any(r["class"] == t["class"] and any(near(p, t[e]) for p in places for e in ("from", "to") if e in t)
                   for t in hidden)
    return {k: [r for r in v if not at_hidden(r)] for k, v in changes.items()}


def map_run(sequence: Path, out: Path, errors: str) -> None:
    """Map ``sequence`` into the run folder ``out`` as `semmap run --instances oracle` does."""
    from typer.testing import CliRunner

    from semmap.cli import app

    r = CliRunner().invoke(app, ["run", str(sequence), "--out", str(out), "--resolution", "0.05",
                                 "--instances", "oracle", "--instance-errors", errors, "--no-cloud"])
    if r.exit_code != 0:
        raise RuntimeError(f"semmap run {sequence} failed: {r.output[-400:]} {r.exception!r}")


def one_scene(root: Path, kind: str, seed: int, args: argparse.Namespace) -> dict:
    """Record, map and diff one room before and after ``changes`` changes; the scored row."""
    from semmap.products.export import export_diff
    from semmap.sim.export import simulate_sequence

    t0 = time.perf_counter()
    runs = []
    for name, n in (("before", 0), ("after", args.changes)):
        seq = root / f"{kind}{seed}-{name}"
        run = root / f"{kind}{seed}-{name}-run"
        if not (run / "objects.json").is_file():  # a --cache folder keeps the recordings and maps of an earlier run
            simulate_sequence(seq, scene_seed=seed, kind=kind, size="small", trajectory=TRAJECTORY,
                              frames=args.frames, fps=1.0, image_size=(320, 240), noise=False, changes=n,
                              changes_seed=seed + 1)
            map_run(seq, run, args.instance_errors)
        runs.append(run)
    summary = export_diff(runs[0], runs[1], root / f"{kind}{seed}-diff", match_radius=args.match_radius)
    truths = json.loads((root / f"{kind}{seed}-after" / "changes.json").read_text())
    why = observability(truths, kind, seed, args.changes, runs)
    hidden = [t for t, w in zip(truths, why, strict=True) if w]
    seen = score([t for t, w in zip(truths, why, strict=True) if not w], without(summary["object_changes"], hidden))
    row = {"scene": f"{kind} small seed {seed}", **score(truths, summary["object_changes"]),
           "unobservable": [f"{t['change']} {t['class']}: {w}" for t, w in zip(truths, why, strict=True) if w],
           "observable": {k: seen[k] for k in ("true", "found", "reported", "correct")},
           "stayed": len(summary["object_changes"]["stayed"]), "s": round(time.perf_counter() - t0, 1)}
    print(json.dumps(row), flush=True)
    return row


def main() -> None:
    """Run the scenes and print the JSON summary line."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="two scenes only (6 changes)")
    ap.add_argument("--frames", type=int, default=30, help="frames per recording (one a second along the orbit)")
    ap.add_argument("--changes", type=int, default=3, help="changes per scene (move, remove, add in turn)")
    ap.add_argument("--instance-errors", default="maskrcnn-like", help="semmap run --instance-errors")
    ap.add_argument("--match-radius", type=float, default=1.0, help="semmap diff --match-radius (m; its default)")
    ap.add_argument("--scenes", default=None,
                    help="rooms as kind:seed,... (default the 7 of SCENES; others measure rooms the method was not "
                         "tuned on)")
    ap.add_argument("--cache", type=Path, default=None,
                    help="keep recordings and maps in this folder and reuse them on the next run (default: none)")
    args = ap.parse_args()
    scenes = SCENES[:2] if args.quick else SCENES
    if args.scenes:
        scenes = tuple((k, int(v)) for k, v in (p.split(":") for p in args.scenes.split(",")))
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        if args.cache is not None:  # one folder per setting, so a cached map is only reused for the same setting
            root = args.cache / f"frames{args.frames}-changes{args.changes}-{args.instance_errors}"
            root.mkdir(parents=True, exist_ok=True)
        rows = [one_scene(root, kind, seed, args) for kind, seed in scenes]
    true, found_, reported, correct = (sum(r[k] for r in rows) for k in ("true", "found", "reported", "correct"))
    o_true, o_found, o_reported, o_correct = (sum(r["observable"][k] for r in rows)
                                              for k in ("true", "found", "reported", "correct"))
    print(json.dumps({"bench": "changes", "changes": true, "precision": round(correct / max(reported, 1), 3),
                      "recall": round(found_ / max(true, 1), 3), "observable_changes": o_true,
                      "observable_precision": round(o_correct / max(o_reported, 1), 3),
                      "observable_recall": round(o_found / max(o_true, 1), 3), "match_radius": args.match_radius,
                      "frames": args.frames, "instance_errors": args.instance_errors, "rows": rows}))


if __name__ == "__main__":
    main()
