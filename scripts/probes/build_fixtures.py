"""Recreate the scratch folder that the bad-input probe's commands expect (/work/shared/probes, issue 31):
``python scripts/probes/build_fixtures.py DIR``. See docs/probes.md. Data-driven: ``FIXTURES`` maps each path the
commands name to its builder; a builder that fails is reported and the rest still get built."""

from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import fixture_table
import fixtures_lib as fx
import surfaces

REPO = Path(__file__).resolve().parents[2]
WRAPPER = """#!/bin/sh
# semmap of {repo} (written by scripts/probes/build_fixtures.py)
PYTHONPATH={repo}/src${{PYTHONPATH:+:$PYTHONPATH}} exec {python} -c \
'import sys; from semmap.cli import main; sys.argv[0] = "semmap"; sys.exit(main())' "$@"
"""
#: ./capped.sh CMD: the probe ran CMD in a 4 GB memory cgroup; here an address-space limit (RLIMIT_AS) of as much.
CAPPED = """#!/bin/sh
# CMD under a {gb} GB address-space limit (the probe used a 4 GB memory cgroup; exit 137 there = killed for memory)
ulimit -v {kb}
exec "$@"
"""


class Ctx:
    """The scratch folder being built and how to run semmap in it."""

    def __init__(self, root: Path, python: str, cap_gb: int) -> None:
        self.root, self.python, self.cap_gb = root, python, cap_gb
        self.semmap = str(root / ".venv" / "bin" / "semmap")

    def p(self, rel: str) -> Path:
        return self.root / rel

    def run(self, *args: str, check: bool = True) -> subprocess.CompletedProcess:
        """Run ``semmap ARGS`` in the scratch folder (the repository's code)."""
        proc = subprocess.run([self.semmap, *args], cwd=self.root, capture_output=True, text=True, errors="replace")
        if check and proc.returncode != 0:
            raise RuntimeError(f"semmap {' '.join(args)} failed ({proc.returncode}): {proc.stderr[-800:]}")
        return proc


# ------------------------------------------------------------------------------------------------ base folders
def tools(ctx: Ctx, _path: Path) -> None:
    """.venv/bin/semmap (this repository's code), ./capped.sh and weights/ as the commands name them."""
    venv = ctx.p(".venv/bin")
    venv.mkdir(parents=True, exist_ok=True)
    fx.write(venv / "semmap", WRAPPER.format(repo=REPO, python=ctx.python))
    fx.write(ctx.p("capped.sh"), CAPPED.format(gb=ctx.cap_gb, kb=ctx.cap_gb * 1024 * 1024))
    for f in (venv / "semmap", ctx.p("capped.sh")):
        f.chmod(0o755)
    link = ctx.p("weights")
    if link.is_symlink() and link.resolve() != (REPO / "weights").resolve():
        link.unlink()  # a link to another checkout's weights (or a dangling one)
    if not link.exists():
        os.symlink(REPO / "weights", link)


def simulate(*args: str):
    """Builder: ``semmap simulate --out PATH ARGS``."""
    return lambda ctx, path: ctx.run("simulate", "--out", str(path.relative_to(ctx.root)), *args)


def semmap_run(*args: str):
    """Builder: ``semmap run ARGS --out PATH``."""
    return lambda ctx, path: ctx.run("run", *args, "--out", str(path.relative_to(ctx.root)))


def train_run(ctx: Ctx, path: Path, model: str, iterations: int) -> None:
    ctx.run("train", "--model", model, "--data", "sim/train", "--val", "sim/val", "--out",
            str(path.relative_to(ctx.root)), "--iterations", str(iterations), "--eval-every", str(iterations),
            "--batch", "4", "--threads", "1")


def train_data(ctx: Ctx, path: Path, seeds: tuple[int, ...], frames: int) -> None:
    """Folders of 160x120 simulated frames (semmap train --data)."""
    for name, seed in zip("abcdefgh", seeds, strict=False):
        simulate("--frames", str(frames), "--scene-seed", str(seed), "--image-size", "160x120")(ctx, path / name)


def ros1_bag(ctx: Ctx, path: Path) -> None:
    """bags/rec.bag: 8 frames of sim/office as a ROS 1 bag (colour, aligned depth, CameraInfo, /tf)."""
    frames = load_frames(ctx, "sim/office", 8)
    path.parent.mkdir(parents=True, exist_ok=True)
    ros_helpers().write_bag(path, frames, kind="ros1")


def checkpoint_folder(ctx: Ctx, path: Path) -> None:
    """h/ckpt_saved: the .partial folder of a run of sim/office killed (-9) after its first checkpoint."""
    out = ctx.p("outputs/ck_src")
    staging = out.parent / f".{out.name}.partial"
    shutil.rmtree(staging, ignore_errors=True)
    shutil.rmtree(out, ignore_errors=True)
    proc = subprocess.Popen([ctx.semmap, "run", "sim/office", "--out", "outputs/ck_src", "--semantics", "oracle",
                             "--checkpoint-every", "3"], cwd=ctx.root, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, start_new_session=True)
    deadline = time.time() + 300
    while time.time() < deadline and proc.poll() is None and not (staging / "checkpoint.npz").exists():
        time.sleep(0.05)
    time.sleep(0.3)
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    if not (staging / "checkpoint.npz").exists():
        raise RuntimeError("the run finished or failed before writing a checkpoint")
    shutil.copytree(staging, path)
    shutil.rmtree(staging, ignore_errors=True)


# ------------------------------------------------------------------------------------------------ frames
def ros_helpers():
    sys.path.insert(0, str(REPO / "tests"))
    import ros_helpers

    return ros_helpers


def load_frames(ctx: Ctx, seq: str, n: int) -> list:
    sys.path.insert(0, str(REPO / "src"))
    from semmap.datasets import open_dataset

    frames = []
    for frame in open_dataset(str(ctx.p(seq))):
        frames.append(frame)
        if len(frames) == n:
            break
    return frames


# ------------------------------------------------------------------------------------------------ building
def tables(probe: str) -> tuple[dict, set[str]]:
    """(fixture table, fixtures rebuilt on every build) of the probe ``bad-input`` or ``new-surfaces``."""
    me = sys.modules[__name__]
    if probe == "new-surfaces":
        victims = surfaces.victims()
        return surfaces.table(me) | victims, {".venv/bin/semmap", *victims}
    return fixture_table.table(me), fixture_table.ALWAYS


def build(root: Path, *, only: str | None, python: str, cap_gb: int, rebuild: bool,
          probe: str = "bad-input") -> dict[str, str]:
    """Build every fixture of the probe's table that is missing (all of them with ``rebuild``); {path: error}."""
    import re

    ctx = Ctx(root, python, cap_gb)
    root.mkdir(parents=True, exist_ok=True)
    failed: dict[str, str] = {}
    table, always = tables(probe)
    for rel, builder in table.items():
        if only and not re.search(only, rel):
            continue
        path = ctx.p(rel)
        if os.path.lexists(path) and not rebuild and rel not in always:
            continue
        fixture_table.remove(path)
        started = time.time()
        try:
            builder(ctx, path)
        except Exception as exc:
            failed[rel] = f"{type(exc).__name__}: {exc}"
            print(f"FAILED {rel}: {failed[rel]}", file=sys.stderr)
            continue
        if time.time() - started > 2:
            print(f"built {rel} ({time.time() - started:.1f} s)", file=sys.stderr)
    return failed


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("dir", type=Path, help="scratch folder (created); the commands run from here")
    ap.add_argument("--only", help="build only fixtures whose path matches this regex")
    ap.add_argument("--rebuild", action="store_true", help="rebuild fixtures that exist (default: only missing "
                    "ones, plus the victims and mounts, which are always rebuilt)")
    ap.add_argument("--python", default=str(Path(sys.executable)), help="python of the venv that runs semmap")
    ap.add_argument("--cap-gb", type=int, default=4, help="address-space limit of ./capped.sh (GB)")
    ap.add_argument("--probe", choices=("bad-input", "new-surfaces"), default="bad-input",
                    help="whose fixtures: the bad-input probe of 2026-11-25 or the new-surfaces one of 2026-11-28")
    args = ap.parse_args()
    failed = build(args.dir.resolve(), only=args.only, python=args.python, cap_gb=args.cap_gb, rebuild=args.rebuild,
                   probe=args.probe)
    notes = (fixture_table.NOT_REPRODUCIBLE if args.probe == "bad-input" else {}) | failed
    (args.dir / "FIXTURES.json").write_text(json.dumps({"not_built": notes}, indent=1))
    print(f"{len(tables(args.probe)[0])} fixtures in the table; {len(failed)} failed; "
          f"notes in {args.dir / 'FIXTURES.json'}")


if __name__ == "__main__":
    np.seterr(all="ignore")
    main()
