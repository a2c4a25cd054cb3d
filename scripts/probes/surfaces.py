"""The probe of the new commands (2026-11-28, issue 48: /work/shared/probes/new-surfaces-2026-11-28.*) for the
harness: its TSV, the cases it interrupted (SIGINT after n seconds; the TSV only records their exit 124), how a
row it called SILENT-WRONG counts as fixed, and the fixtures its non-GOOD rows and happy paths need
(``build_fixtures.py DIR --probe new-surfaces``)."""

from __future__ import annotations

import json
import re
import shutil
from functools import partial
from pathlib import Path

import numpy as np

TSV = Path("/work/shared/probes/new-surfaces-2026-11-28.tsv")
#: Cases the probe interrupted with SIGINT after this many seconds (its case files said INTn: 3, 4 and 15 s there),
#: later here so that a busy machine has finished importing semmap (a Ctrl-C while Python imports is Python's).
INTERRUPTS = {"int_merge": 8.0, "int_esdf": 8.0, "ct_doc_ctrlc": 25.0, "ct_ctrlc": 12.0, "si_ctrlc": 8.0,
              "lo_ctrlc": 10.0}
#: A SILENT-WRONG row is fixed when its command is refused, warns, or (here) gives the right result.
RIGHT_RESULT = {"sg_from_cwd": "(from the layout)"}
#: Ground-truth classes of a labelled PLY: the map's own voxels (h/gt_ok.ply), and the same 100 m away.
GT_SHIFT = {"h/gt_ok.ply": 0.0, "h/gt_far.ply": 100.0}


#: Paths of the probe's scratch folder in a command (``../`` when it runs from o/).
SCRATCH_PATH = re.compile(r"(?:\.\./)?((?:h|sim|runs|data|w|o)/[\w./-]*)")


def unbuilt(command: str, fixtures: set[str]) -> list[str]:
    """The paths ``command`` reads that no fixture of the table makes (an ONNX model, a transformers folder, a
    hostile PLY ...): the case is then NOT-REPRODUCED. Paths under ``o/`` are outputs of earlier cases, and a path
    that is missing on purpose (``nothere``) is no fixture."""
    out = []
    for path in SCRATCH_PATH.findall(command):
        path = path.rstrip("/.")
        made = any(path == k or path.startswith(k + "/") for k in fixtures)
        if not made and not path.startswith("o/") and "nothere" not in path:
            out.append(path)
    return out


def silent_fixed(name: str, rc: int, text: str) -> bool:
    """Whether a case the probe found silently wrong now says something or gets it right."""
    if name in RIGHT_RESULT:
        return RIGHT_RESULT[name] in text
    return rc != 0 or "warning" in text.lower()


# ------------------------------------------------------------------------------------------------ builders
def _semmap(*args: str):
    """Builder: ``semmap ARGS`` with ``{out}`` the fixture's path."""
    def build(ctx, path: Path) -> None:
        ctx.run(*(a.format(out=str(path.relative_to(ctx.root))) for a in args))
    return build


def _transform(rows: list[str], _ctx, path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(rows) + "\n")


def _translation(t: str) -> list[str]:
    return [f"1 0 0 {t}", "0 1 0 0", "0 0 1 0", "0 0 0 1"]


def _gt_ply(shift: float, ctx, path: Path) -> None:
    """The occupied voxels of runs/a's OctoMap as ScanNet-style labelled vertices, moved ``shift`` m along x."""
    import sys

    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "src"))
    from semmap.io.map_files import load_map
    from semmap.types import EMPTY_LABEL

    cloud = load_map(ctx.p("runs/a/map.semmap")).cloud()
    keep = (cloud.labels != EMPTY_LABEL) & (cloud.labels != 0)
    rows = np.zeros(int(keep.sum()), [("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("label", "<u2")])
    rows["x"], rows["y"], rows["z"] = (cloud.centers[keep] + [shift, 0.0, 0.0]).T
    rows["label"] = cloud.labels[keep]
    header = ["ply", "format binary_little_endian 1.0", f"element vertex {len(rows)}", "property float x",
              "property float y", "property float z", "property ushort label", "end_header"]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(("\n".join(header) + "\n").encode() + rows.tobytes())


def _run_copy(edit, ctx, path: Path) -> None:
    """A copy of runs/a with its config.json edited (``edit(text) -> text``)."""
    shutil.copytree(ctx.p("runs/a"), path)
    (path / "config.json").write_text(edit((path / "config.json").read_text()))


def _missing_dataset(text: str) -> str:
    config = json.loads(text)
    config["input"]["dataset"] = "nowhere/seq"
    return json.dumps(config, indent=2)


def _copy(src: str, ctx, path: Path) -> None:
    s = ctx.p(src)
    path.parent.mkdir(parents=True, exist_ok=True)
    (shutil.copytree if s.is_dir() else shutil.copy2)(s, path)


def _seven_scenes(_ctx, path: Path) -> None:
    """data/7s: frames 0-9 of the shared 7-Scenes redkitchen sequence, with its intrinsics."""
    src = Path("/work/shared/data/7scenes-redkitchen")
    path.mkdir(parents=True)
    for f in sorted(src.iterdir()):
        if f.name == "camera-intrinsics.txt" or f.name.split(".")[0] in {f"frame-{i:06d}" for i in range(10)}:
            shutil.copy2(f, path / f.name)


def _python(ctx, path: Path) -> None:
    """.venv/bin/python: the interpreter that runs semmap, with this checkout's sources first (a bare link to a
    venv's python would not find the venv)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    repo = Path(__file__).resolve().parents[2]
    path.write_text(f'#!/bin/sh\nPYTHONPATH={repo}/src${{PYTHONPATH:+:$PYTHONPATH}} exec {ctx.python} "$@"\n')
    path.chmod(0o755)


def _link(target, ctx, path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.symlink_to(target(ctx))


def table(b) -> dict:
    """Fixtures in build order: path relative to the scratch folder -> builder(ctx, path)."""
    small = ("--size", "small", "--image-size", "320x240")
    maps = ("--maps", "octomap,points,tsdf", "--instances", "oracle", "--no-cloud")
    t = {
        ".venv/bin/semmap": b.tools,
        ".venv/bin/python": _python,
        "w": partial(_link, lambda ctx: b.REPO / "weights" / "espnetv2"),
        "sim/a": _semmap("simulate", "--out", "{out}", "--frames", "30", *small),
        "sim/b": _semmap("simulate", "--out", "{out}", "--frames", "20", "--trajectory", "walk",
                         "--trajectory-seed", "7", *small),
        "sim/chg": _semmap("simulate", "--out", "{out}", "--frames", "30", "--changes", "1", *small),
        "data/7s": _seven_scenes,
        "runs/a": _semmap("run", "sim/a", "--out", "{out}", *maps),
        "runs/chg": _semmap("run", "sim/chg", "--out", "{out}", *maps),
        "h/T_ident.txt": partial(_transform, _translation("0")),
        "h/T_far.txt": partial(_transform, _translation("50")),
        "h/T_huge.txt": partial(_transform, _translation("1e12")),
        "h/T_nan.txt": partial(_transform, ["1 0 0 0", "0 1 0 nan", "0 0 1 0", "0 0 0 1"]),
        "h/T_inf.txt": partial(_transform, ["1 0 0 0", "0 1 0 inf", "0 0 1 0", "0 0 0 1"]),
        **{k: partial(_gt_ply, v) for k, v in GT_SHIFT.items()},
        "h/map.ot": partial(_copy, "runs/a/map.ot"),
        "h/run_cfg_missing": partial(_run_copy, _missing_dataset),
        "h/run_badcfg": partial(_run_copy, lambda _text: "{garbage"),
        "h/cm_ok.json": partial(_transform, ['{"chair": "chair"}']),
        "h/emptydir": lambda _ctx, path: path.mkdir(parents=True),
        "h/train/t1": _semmap("simulate", "--out", "{out}", "--frames", "4", "--size", "small", "--image-size",
                              "160x120"),
        "o/tr_env/best.pt": partial(_copy, "weights/fcn.pt"),
        "o/mesh": _semmap("export", "mesh", "runs/a", "--out", "{out}"),
        "h/mesh.ply": partial(_copy, "o/mesh/mesh.ply"),
        # docs/continue.md's recipe, for the one Ctrl-C case of --continue (ct_doc_ctrlc): the slowest, so last
        "sim/rec1": _semmap("simulate", "--out", "{out}", "--frames", "300", *small),
        "sim/rec2": _semmap("simulate", "--out", "{out}", "--frames", "60", "--trajectory", "walk", *small),
        "runs/rec1": _semmap("run", "sim/rec1", "--out", "{out}", "--maps", "octomap,points", "--no-cloud"),
    }
    return t


def victims() -> dict:
    """Fixtures rebuilt on every build: the earlier exports a case replaces (D1's victims)."""
    return {"o/grid_victim": _semmap("export", "grid", "runs/a", "--out", "{out}"),
            "o/diff_victim": _semmap("diff", "runs/a", "runs/chg", "--out", "{out}")}
