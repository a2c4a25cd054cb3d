"""Peak memory of a long run against the number of frames: a simulated walk of 10,000 frames mapped as `semmap run`
maps it (ground-truth poses, labels as semantics), with the process's resident memory and the map's own bytes
recorded every few hundred frames. What does not belong to the map should stay flat.

    python benchmarks/bench_memory.py [--frames 10000] [--every 250] [--size 320x240] [--quick]

Prints one JSON line per sample (frames, RSS MiB, peak RSS MiB, map MiB, RSS minus map MiB), then a JSON summary:
the growth of RSS-minus-map per 1,000 frames over the second half of the run (after the map's first growth and
numba's compilation), and the peak.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np


def rss_mb() -> tuple[float, float]:
    """(current, peak) resident memory of this process in MiB (Linux /proc)."""
    values = {}
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(("VmRSS:", "VmHWM:")):
            key, kb = line.split()[:2]
            values[key[:-1]] = int(kb) / 1024
    return values["VmRSS"], values["VmHWM"]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=10_000)
    ap.add_argument("--every", type=int, default=250, help="frames between two samples")
    ap.add_argument("--size", default="320x240", help="image size (the simulator renders every frame)")
    ap.add_argument("--resolution", type=float, default=0.05)
    ap.add_argument("--quick", action="store_true", help="1,000 frames")
    args = ap.parse_args()
    frames = 1000 if args.quick else args.frames

    from semmap.config import InputConfig, MappingConfig, OutputConfig, RunConfig
    from semmap.datasets.simulated import SimulatedDataset
    from semmap.pipeline import Pipeline
    from semmap.sim.scene import generate_scene
    from semmap.sim.trajectory import make_trajectory
    from semmap.types import CameraIntrinsics

    width, height = (int(v) for v in args.size.split("x"))
    f = 525.0 * width / 640
    camera = CameraIntrinsics(width, height, f, f, (width - 1) / 2, (height - 1) / 2)
    scene = generate_scene(0, "office", "large")
    poses = make_trajectory(scene, "walk", frames, seed=0)
    dataset = SimulatedDataset(scene, poses, intrinsics=camera, name=f"sim-walk-{frames}")
    samples: list[dict] = []
    start = time.perf_counter()

    class Measured(Pipeline):
        def _after_frame(self, frame, mapper, pose_of, record) -> None:
            super()._after_frame(frame, mapper, pose_of, record)
            n = len(record.poses)
            if n % args.every == 0 or n == frames:
                rss, peak = rss_mb()
                map_mb = sum(m.describe().get("bytes_in_memory", 0) for m in mapper.maps) / 2**20
                sample = {"frames": n, "rss_mb": round(rss, 1), "peak_rss_mb": round(peak, 1),
                          "map_mb": round(map_mb, 1), "rss_minus_map_mb": round(rss - map_mb, 1),
                          "seconds": round(time.perf_counter() - start, 1)}
                samples.append(sample)
                print(json.dumps(sample), flush=True)

    out = Path(tempfile.mkdtemp(prefix="semmap-bench-memory-")) / "out"
    config = RunConfig(input=InputConfig(dataset=Path(dataset.name)), mapping=MappingConfig(resolution=args.resolution),
                       output=OutputConfig(out=out, plots=False))
    Measured(config, dataset=dataset).run()
    second_half = [s for s in samples if s["frames"] >= frames // 2]
    x = np.array([s["frames"] for s in second_half], float)
    y = np.array([s["rss_minus_map_mb"] for s in second_half], float)
    slope = float(np.polyfit(x, y, 1)[0] * 1000) if len(x) >= 2 else float("nan")
    print(json.dumps({"frames": frames, "image": args.size, "resolution": args.resolution,
                      "peak_rss_mb": max(s["peak_rss_mb"] for s in samples),
                      "final_map_mb": samples[-1]["map_mb"],
                      "rss_minus_map_growth_mb_per_1000_frames": round(slope, 2),
                      "rss_minus_map_first_last_mb": [second_half[0]["rss_minus_map_mb"],
                                                      second_half[-1]["rss_minus_map_mb"]],
                      "seconds": round(time.perf_counter() - start, 1)}))


if __name__ == "__main__":
    main()
