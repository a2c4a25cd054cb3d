"""Speed guard: the working tree against a baseline revision, in the same session on the same frames, stage by stage.

Checks REV out with ``git worktree add`` into a temporary folder (beside a link to ``../shared``, so that both
trees' benchmarks find the same data) and runs, with this Python and ``PYTHONPATH`` pointing at each tree's
``src``, in turns (baseline, working tree, baseline, ...):

- ``octree``: that tree's ``benchmarks/bench_octree_vs_octomap.py --quick``: ms per frame and per insertion stage
  of each case (consecutive, sparse) and resolution;
- ``demo``: ``semmap demo --frames 60``: the report's ms per frame of each stage;
- ``online``: ``semmap run`` on the 7-Scenes frames in ``../shared`` as the online benchmark's 5 cm row runs it
  (``--online --poses slam``, ESPNetv2 in ONNX every 5th frame, 150 frames): ms per frame (1000 / frames per
  second) and per stage.

Each stage keeps its best time over the rounds (a shared machine disturbs some runs).  Prints every stage's time
in both trees and their ratio (working / baseline), and exits 1 when a stage is more than ``--tolerance`` slower
and no line of the allow-list (``benchmarks/perf_guard_allow.txt``: ``PATTERN  reason``, shell-style patterns
of stage names) names it.  Stages under ``--min-ms`` in both trees are shown but never fail (too short to time).
Not a test and not part of CI: CONTRIBUTING.md asks for it before a change lands.  It takes a while (about 10
minutes for two rounds of everything on a quiet machine); ``--probes`` picks fewer.  On a machine other work
keeps busy, ``--threads 1`` compares serial timings: a parallel pass waits for a core the others hold, which
makes its times swing by ten times.

    python benchmarks/perf_guard.py --against REV [--probes octree,demo,online] [--rounds 2] [--threads 1]
"""

from __future__ import annotations

import argparse
import fnmatch
import json
import os
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared"
SEVEN_SCENES = SHARED / "data" / "7scenes-redkitchen"
ESPNET_WEIGHTS = SHARED / "weights" / "espnetv2" / "espnetv2_s_2.0_pascal_384x384.pth"
ALLOW = Path(__file__).with_name("perf_guard_allow.txt")
PROBES = ("octree", "demo", "online")
DEMO_FRAMES = 60
ONLINE_FRAMES = 150
ONLINE_RESOLUTION = 0.05
SEGMENT_EVERY = 5


@dataclass(frozen=True)
class Row:
    """One stage in both trees: milliseconds (None where a tree has no such stage), ratio and verdict."""

    stage: str
    base_ms: float | None
    work_ms: float | None
    verdict: str  # ok | slower | allowed | short | new | gone
    reason: str = ""

    @property
    def ratio(self) -> float | None:
        if self.base_ms is None or self.work_ms is None or self.base_ms <= 0:
            return None
        return self.work_ms / self.base_ms


def read_allow(path: Path) -> list[tuple[str, str]]:
    """The allow-list: one ``PATTERN  reason`` per line (``#`` starts a comment); a pattern without a reason is
    refused, since the reason is the point of the list."""
    out = []
    if not path.is_file():
        return out
    for n, raw in enumerate(path.read_text().splitlines(), 1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        pattern, _, reason = line.partition(" ")
        if not reason.strip():
            raise SystemExit(f"{path}:{n}: '{pattern}' has no reason (write: PATTERN  why it may be slower)")
        out.append((pattern, reason.strip()))
    return out


def compare(base: dict[str, float], work: dict[str, float], *, tolerance: float, allow: list[tuple[str, str]],
            min_ms: float) -> list[Row]:
    """Every stage of either tree with its verdict: ``slower`` when the working tree takes more than
    ``1 + tolerance`` times the baseline's time and no allow-list pattern names the stage (``allowed`` when one
    does), ``short`` when both take under ``min_ms``, ``new`` / ``gone`` for a stage only one tree has."""
    rows = []
    for stage in sorted(set(base) | set(work)):
        b, w = base.get(stage), work.get(stage)
        if b is None or w is None:
            rows.append(Row(stage, b, w, "new" if b is None else "gone"))
            continue
        reason = next((why for pattern, why in allow if fnmatch.fnmatchcase(stage, pattern)), "")
        if max(b, w) < min_ms:
            verdict = "short"
        elif w > b * (1.0 + tolerance):
            verdict = "allowed" if reason else "slower"
        else:
            verdict = "ok"
        rows.append(Row(stage, b, w, verdict, reason if verdict == "allowed" else ""))
    return rows


def failures(rows: list[Row]) -> list[Row]:
    return [r for r in rows if r.verdict == "slower"]


def best_of(runs: list[dict[str, float]]) -> dict[str, float]:
    """Each stage's smallest time over the runs that have it."""
    out: dict[str, float] = {}
    for run in runs:
        for stage, ms in run.items():
            out[stage] = min(ms, out.get(stage, ms))
    return out


def octree_stages(result: dict) -> dict[str, float]:
    """Stage times of one ``bench_octree_vs_octomap.py`` JSON line: ``octree/CASE/RES/total`` (mean ms per frame)
    and ``octree/CASE/RES/STAGE``."""
    out = {}
    for case, key in (("consecutive", "results"), ("sparse", "sparse_results")):
        for r in result.get(key, []):
            prefix = f"octree/{case}/{r['resolution']:g}"
            out[f"{prefix}/total"] = float(r["semmap_ms"])
            out.update({f"{prefix}/{k}": float(v) for k, v in r.get("semmap_stage_ms", {}).items()})
    return out


def report_stages(report: dict, prefix: str) -> dict[str, float]:
    """Stage times of a run's report.json: ``PREFIX/frame`` (1000 / frames per second: the frame loop's pace) and
    ``PREFIX/STAGE`` from its ms per frame (``total`` included)."""
    out = {f"{prefix}/{k}": float(v) for k, v in report.get("ms_per_frame", {}).items() if isinstance(v, int | float)}
    fps = report.get("frames_per_second")
    if fps:
        out[f"{prefix}/frame"] = 1e3 / float(fps)
    return out


def last_json(text: str) -> dict:
    """The last line of a benchmark's output that is a JSON object."""
    for line in reversed(text.strip().splitlines()):
        if line.startswith("{"):
            return json.loads(line)
    raise ValueError("no JSON line in the benchmark's output")


class Tree:
    """A source tree the probes run against: its root, and the environment that imports its ``src``."""

    def __init__(self, name: str, root: Path, threads: int | None = None) -> None:
        self.name, self.root = name, root
        self.env = {**os.environ, "PYTHONPATH": str(root / "src")}
        if threads:  # numba's and the runtimes' threads (ONNX Runtime, torch read OMP_NUM_THREADS)
            self.env.update(NUMBA_NUM_THREADS=str(threads), OMP_NUM_THREADS=str(threads))

    def run(self, args: list[str], timeout: float = 3600) -> str:
        r = subprocess.run([sys.executable, *args], cwd=self.root, env=self.env, capture_output=True, text=True,
                           timeout=timeout)
        if r.returncode != 0:
            raise SystemExit(f"{self.name}: {' '.join(args)} failed:\n{r.stderr[-3000:]}")
        return r.stdout

    def octree(self, tmp: Path) -> dict[str, float]:
        return octree_stages(last_json(self.run(["benchmarks/bench_octree_vs_octomap.py", "--quick"])))

    def demo(self, tmp: Path) -> dict[str, float]:
        out = tmp / f"demo-{self.name}"
        self.run(["-m", "semmap.cli", "demo", "--frames", str(DEMO_FRAMES), "--out", str(out)])
        return report_stages(json.loads((out / "report.json").read_text()), "demo")

    def online(self, tmp: Path) -> dict[str, float]:
        out = tmp / f"online-{self.name}"
        self.run(["-m", "semmap.cli", "run", str(SEVEN_SCENES), "--out", str(out), "--resolution",
                  str(ONLINE_RESOLUTION), "--poses", "slam", "--segmenter", "espnetv2", "--weights",
                  str(ESPNET_WEIGHTS), "--backend", "onnx", "--segment-every", str(SEGMENT_EVERY), "--max-frames",
                  str(ONLINE_FRAMES), "--online"])
        return report_stages(json.loads((out / "report.json").read_text()), f"online/{ONLINE_RESOLUTION:g}")


def checkout(rev: str, tmp: Path) -> Path:
    """REV checked out (detached) in ``tmp/tree``, with ``tmp/shared`` linking the data beside this repository."""
    tree = tmp / "tree"
    subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "--detach", str(tree), rev], check=True,
                   capture_output=True, text=True)
    if SHARED.is_dir():
        (tmp / "shared").symlink_to(SHARED)
    return tree


def print_rows(rows: list[Row]) -> None:
    def ms(v: float | None) -> str:
        return "-" if v is None else f"{v:.2f}"

    width = max((len(r.stage) for r in rows), default=10)
    print(f"{'stage':{width}s} {'base ms':>9s} {'work ms':>9s} {'ratio':>6s}  verdict")
    for r in rows:
        ratio = "-" if r.ratio is None else f"{r.ratio:.2f}"
        note = f"  ({r.reason})" if r.reason else ""
        print(f"{r.stage:{width}s} {ms(r.base_ms):>9s} {ms(r.work_ms):>9s} {ratio:>6s}  {r.verdict}{note}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--against", required=True, help="baseline revision (commit, branch or tag)")
    ap.add_argument("--probes", default=",".join(PROBES), help=f"comma-separated, of {', '.join(PROBES)}")
    ap.add_argument("--rounds", type=int, default=2, help="runs of each probe per tree, in turns; the best counts")
    ap.add_argument("--tolerance", type=float, default=0.10, help="slower than the baseline by more than this fails")
    ap.add_argument("--min-ms", type=float, default=0.5, help="stages shorter than this in both trees never fail")
    ap.add_argument("--allow", type=Path, default=ALLOW, help="allow-list of stages that may be slower, with reasons")
    ap.add_argument("--threads", type=int, default=None, help="threads of numba and the runtimes in both trees (1: "
                    "serial timings, far steadier on a busy machine; default: as the benchmarks run)")
    args = ap.parse_args()
    probes = [p.strip() for p in args.probes.split(",") if p.strip()]
    unknown = sorted(set(probes) - set(PROBES))
    if unknown or args.rounds < 1 or args.tolerance < 0:
        raise SystemExit(f"probes must be of {PROBES} (got {unknown}), --rounds >= 1, --tolerance >= 0")
    if "online" in probes and not (SEVEN_SCENES.is_dir() and ESPNET_WEIGHTS.is_file()):
        raise SystemExit(f"the online probe needs {SEVEN_SCENES} and {ESPNET_WEIGHTS}: leave it out (--probes)")
    allow = read_allow(args.allow)
    with tempfile.TemporaryDirectory(prefix="semmap-perf-guard-") as tmp_name:
        tmp = Path(tmp_name)
        try:
            trees = [Tree("base", checkout(args.against, tmp), args.threads), Tree("work", ROOT, args.threads)]
            runs: dict[str, list[dict[str, float]]] = {t.name: [] for t in trees}
            for probe in probes:
                for i in range(args.rounds):
                    for tree in trees:
                        print(f"{probe}: {tree.name} round {i + 1} of {args.rounds}", file=sys.stderr)
                        runs[tree.name].append(getattr(tree, probe)(tmp))
        finally:
            subprocess.run(["git", "-C", str(ROOT), "worktree", "remove", "--force", str(tmp / "tree")],
                           capture_output=True)
    rows = compare(best_of(runs["base"]), best_of(runs["work"]), tolerance=args.tolerance, allow=allow,
                   min_ms=args.min_ms)
    threads = "" if args.threads is None else f", {args.threads} thread(s)"
    print(f"working tree against {args.against}, best of {args.rounds} rounds{threads}, tolerance "
          f"{args.tolerance:.0%}:")
    print_rows(rows)
    slower = failures(rows)
    if slower:
        print(f"{len(slower)} stage(s) more than {args.tolerance:.0%} slower and not in {args.allow}: "
              + ", ".join(r.stage for r in slower))
        sys.exit(1)


if __name__ == "__main__":
    main()
