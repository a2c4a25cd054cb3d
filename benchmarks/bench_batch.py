"""`semmap batch` against separate `semmap run`s of the same simulated sequences, in one run: wall time, overhead
and time per sequence, on a local Ray cluster and on two Ray nodes started on this machine (head + one worker
joined by address), and whether every map file is byte-identical to the separate runs'.

    python benchmarks/bench_batch.py [--sequences 8] [--frames 40] [--quick]

The separate runs are `semmap run` processes one after another, as a user would start them (each already uses
both cores); the batches are `semmap batch` processes. Prints one JSON line per mode, then a JSON summary last.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

MAP_FILES = ("map.ot", "map.bt", "map.semmap", "trajectory.txt")


def semmap(*args: str) -> float:
    """Run the semmap CLI; seconds it took."""
    start = time.perf_counter()
    r = subprocess.run([sys.executable, "-m", "semmap.cli", *args], capture_output=True, text=True)
    if r.returncode != 0:
        raise SystemExit(f"semmap {' '.join(args)} failed:\n{r.stderr[-2000:]}")
    return time.perf_counter() - start


def identical(a: Path, b: Path, names: list[str]) -> bool:
    return all((a / n / f).read_bytes() == (b / n / f).read_bytes() for n in names for f in MAP_FILES)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sequences", type=int, default=8)
    ap.add_argument("--frames", type=int, default=40)
    ap.add_argument("--resolution", default="0.05")
    ap.add_argument("--quick", action="store_true", help="2 sequences of 10 frames")
    ap.add_argument("--no-two-nodes", action="store_true", help="skip the two-node cluster")
    args = ap.parse_args()
    n, frames = (2, 10) if args.quick else (args.sequences, args.frames)
    root = Path(tempfile.mkdtemp(prefix="semmap-bench-batch-"))
    from semmap.sim.export import simulate_sequence

    seqs = [simulate_sequence(root / "seqs" / f"seq{i}", scene_seed=i, kind="office", size="small",
                              trajectory=("desk", "walk", "loop", "orbit")[i % 4], frames=frames) for i in range(n)]
    names = [s.name for s in seqs]
    options = ["--resolution", args.resolution]
    semmap("run", str(seqs[0]), "--out", str(root / "warm"), *options)  # numba's cache filled for everyone

    sequential = 0.0
    for seq in seqs:
        sequential += semmap("run", str(seq), "--out", str(root / "separate" / seq.name), *options)
    print(json.dumps({"mode": "separate runs", "sequences": n, "seconds": round(sequential, 1),
                      "seconds_per_sequence": round(sequential / n, 2)}), flush=True)

    results = {"separate": sequential}
    local = semmap("batch", *map(str, seqs), "--out", str(root / "local"), *options)
    results["local"] = local
    summary = json.loads((root / "local" / "batch.json").read_text())
    print(json.dumps({"mode": "batch, local cluster", "seconds": round(local, 1),
                      "overhead": round(local / sequential - 1, 3), "identical": identical(root / "separate",
                                                                                            root / "local", names),
                      "seconds_per_sequence_in_tasks": summary["seconds_per_sequence"]}), flush=True)
    if not args.no_two_nodes:
        from ray.cluster_utils import Cluster

        cluster = Cluster(initialize_head=True, head_node_args={"num_cpus": 1, "include_dashboard": False})
        try:
            cluster.add_node(num_cpus=1)
            cluster.wait_for_nodes()
            two = semmap("batch", *map(str, seqs), "--out", str(root / "two"), "--address", cluster.address,
                         "--cpus-per-run", "1", *options)
        finally:
            cluster.shutdown()
        results["two_nodes"] = two
        summary2 = json.loads((root / "two" / "batch.json").read_text())
        print(json.dumps({"mode": "batch, two Ray nodes on this machine", "seconds": round(two, 1),
                          "overhead": round(two / sequential - 1, 3),
                          "identical": identical(root / "separate", root / "two", names),
                          "nodes_used": len({r["node"] for r in summary2["rows"]}),
                          "seconds_per_sequence_in_tasks": summary2["seconds_per_sequence"]}), flush=True)
    print(json.dumps({"sequences": n, "frames": frames, "separate_s": round(sequential, 1),
                      "local_batch_s": round(local, 1), "local_overhead": round(local / sequential - 1, 3),
                      **({"two_node_batch_s": round(results["two_nodes"], 1),
                          "two_node_overhead": round(results["two_nodes"] / sequential - 1, 3)}
                         if "two_nodes" in results else {}),
                      "separate_s_per_sequence": round(sequential / n, 2), "folder": str(root)}))


if __name__ == "__main__":
    main()
