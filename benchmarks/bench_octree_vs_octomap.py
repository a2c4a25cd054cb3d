"""semmap's SemanticOctoMap against the real OctoMap library (pyoctomap) and an occupancy-only yardstick,
same frames, same run.

Inserts the same back-projected RGB-D frames (7-Scenes from ../shared, or synthetic depth frames when absent;
float32 world points as ``semmap run`` makes them) into semmap (occupancy + colour + top-3 semantics), into
``occupancy_reference.OccupancyReference`` (occupancy only, a plain hash map: the speed limit of the occupancy
part) and into ``pyoctomap.OcTree.insertPointCloud`` with ``discretize=True`` (and ``False`` for the
consecutive case), at 0.05 m and 0.02 m, in two cases: consecutive frames (every 10th, mostly known space)
and sparse frames (every 50th, each bringing much new space).  semmap and the reference are timed in turns,
frame by frame, several times, and each frame's best time counts (a shared machine disturbs some runs).
Prints per-frame times (mean and median over the frames), ratios, the occupied / free / unknown agreement of
semmap and of the reference with OctoMap's discretized insert (and whether the reference's cells and log-odds
equal semmap's), and bytes per leaf; the last line is one JSON object.

    python benchmarks/bench_octree_vs_octomap.py [--quick] [--frames N] [--sparse-frames N] [--repeats R]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from occupancy_reference import OccupancyReference
from semmap.geometry import backproject_world
from semmap.io.octomap_files import decode_octomap
from semmap.keys import pack_keys
from semmap.maps.semantic_octomap import SemanticOctoMap, compile_kernels
from semmap.types import CameraIntrinsics, TopKProbs

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data" / "7scenes-redkitchen"


def load_frames(n: int, stride: int) -> tuple[str, list[tuple[np.ndarray, np.ndarray, np.ndarray]]]:
    """(source name, [(world points float32 (N,3), colours (N,3) uint8, origin (3,))])."""
    if SHARED.is_dir():
        from semmap.datasets import open_dataset

        out = []
        for f in open_dataset(SHARED, "7scenes", stride=stride, max_frames=n):
            pts, pix = backproject_world(f.depth, f.intrinsics, f.T_world_cam)  # as Mapper.integrate does
            out.append((pts, f.rgb.reshape(-1, 3)[pix], f.T_world_cam[:3, 3]))
        return f"7scenes-redkitchen ({SHARED})", out
    return "synthetic room (../shared absent)", synthetic_frames(n)


def synthetic_frames(n: int) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Depth images of a 6 x 5 x 3 m box room with a few blocks, seen along a circle (640x480)."""
    cam = CameraIntrinsics(640, 480, 525.0, 525.0, 319.5, 239.5)
    rng = np.random.default_rng(0)
    u, v = np.meshgrid(np.arange(640), np.arange(480))
    rays_cam = np.stack([(u - cam.cx) / cam.fx, (v - cam.cy) / cam.fy, np.ones_like(u, float)], -1).reshape(-1, 3)
    lo, hi = np.array([-3.0, -2.5, 0.0]), np.array([3.0, 2.5, 3.0])
    out = []
    for i in range(n):
        a = 2 * np.pi * i / max(n, 8)
        origin = np.array([0.8 * np.cos(a), 0.8 * np.sin(a), 1.4])
        fwd = np.array([np.cos(a + 1.2), np.sin(a + 1.2), -0.15])
        fwd /= np.linalg.norm(fwd)
        right = np.cross(fwd, [0, 0, 1.0])
        right /= np.linalg.norm(right)
        down = np.cross(fwd, right)
        R = np.stack([right, down, fwd], 1)
        d = rays_cam @ R.T
        with np.errstate(divide="ignore", invalid="ignore"):
            t = np.min(np.where(d > 0, (hi - origin) / d, np.where(d < 0, (lo - origin) / d, np.inf)), axis=1)
        t *= 1 + rng.normal(0, 0.002, t.shape)
        pts = origin + d * t[:, None]
        cols = (np.abs(np.sin(pts * 3.0)) * 200 + 30).astype(np.uint8)
        out.append((pts, cols, origin))
    return out


def fake_semantics(colors: np.ndarray) -> TopKProbs:
    """Deterministic top-3 class sets from the colours (the benchmark measures fusion cost, not accuracy)."""
    c = colors.astype(np.int64)
    first = (c[:, 0] // 64 + 4 * (c[:, 1] // 64)) % 20 + 1
    labels = np.stack([first, first % 20 + 1, (first + 5) % 20 + 1], 1).astype(np.uint16)
    probs = np.broadcast_to(np.array([0.7, 0.2, 0.05], np.float32), labels.shape).copy()
    return TopKProbs(labels, probs)


def octomap_states(tree, resolution: float) -> tuple[np.ndarray, np.ndarray]:
    """Packed finest-level keys and occupied flags of a pyoctomap tree (via its .ot bytes)."""
    leaves = decode_octomap(tree.write(), "pyoctomap")
    keys, src = leaves.expand()
    return pack_keys(keys), leaves.occupied(tree.getOccupancyThresLog())[src]


def agreement(a_keys, a_occ, b_keys, b_occ) -> float:
    """Share of cells known to either map whose occupied / free / unknown state is the same."""
    keys = np.concatenate([a_keys, b_keys])
    state = np.concatenate([np.where(a_occ, 2, 1), np.where(b_occ, 2, 1)]).astype(np.int8)
    src = np.concatenate([np.zeros(a_keys.size, np.int8), np.ones(b_keys.size, np.int8)])
    order = np.lexsort((src, keys))
    keys, state, src = keys[order], state[order], src[order]
    uniq, first, counts = np.unique(keys, return_index=True, return_counts=True)
    both = counts == 2
    same = both & (state[first] == state[np.minimum(first + 1, keys.size - 1)])
    return float(same.sum() / max(uniq.size, 1))


def timed_inserts(frames, resolution: float, repeats: int) -> tuple[SemanticOctoMap, OccupancyReference, dict]:
    """semmap's full insertion and the occupancy-only reference, frame by frame in turns, ``repeats`` times from
    empty maps; each frame's best time of each (the machine may be shared: the best is the least disturbed)."""
    n = len(frames)
    best_sem, best_ref = np.full(n, np.inf), np.full(n, np.inf)
    stage_ms: dict[str, np.ndarray] = {}
    sems = [fake_semantics(c) for _, c, _ in frames]
    for _ in range(repeats):
        m, ref = SemanticOctoMap(resolution), OccupancyReference(resolution)
        for i, ((p, c, o), sem) in enumerate(zip(frames, sems, strict=True)):
            t = time.perf_counter()
            st = m.insert_points(p, o, colors=c, semantics=sem)
            best_sem[i] = min(best_sem[i], time.perf_counter() - t)
            t = time.perf_counter()
            ref.insert_points(p, o)
            best_ref[i] = min(best_ref[i], time.perf_counter() - t)
            for k, v in st.ms.items():
                best = stage_ms.setdefault(k, np.full(n, np.inf))
                best[i] = min(best[i], v)
    times = {"semmap": best_sem * 1e3, "reference": best_ref * 1e3,
             "stages": {k: float(np.median(v)) for k, v in stage_ms.items()}}
    return m, ref, times


def bench_resolution(frames, resolution: float, *, repeats: int, run_octomap_raw: bool) -> dict:
    import pyoctomap

    compile_kernels()  # numba compiles (or loads) every kernel before anything is timed
    warm = OccupancyReference(resolution)
    warm.insert_points(*frames[0][::2])
    m, ref, times = timed_inserts(frames, resolution, repeats)

    def run_octomap(discretize: bool):
        tree = pyoctomap.OcTree(resolution)
        times = []
        for p, _, o in frames:
            pts = np.ascontiguousarray(p, np.float64)
            t = time.perf_counter()
            tree.insertPointCloud(pts, np.asarray(o, np.float64), discretize=discretize)
            times.append(time.perf_counter() - t)
        return tree, float(np.mean(times) * 1e3)

    tree_d, oct_d_ms = run_octomap(True)
    oct_ms = run_octomap(False)[1] if run_octomap_raw else None
    sem_ms, sem_median = float(np.mean(times["semmap"])), float(np.median(times["semmap"]))
    ref_ms, ref_median = float(np.mean(times["reference"])), float(np.median(times["reference"]))
    c = m.cells()
    o_keys, o_occ = octomap_states(tree_d, resolution)
    agree = agreement(c.packed, m.is_occupied(c.logodds), o_keys, o_occ)
    ref_keys, ref_logodds = ref.cells()
    ref_agree = agreement(ref_keys, m.is_occupied(ref_logodds), o_keys, o_occ)
    return {
        "resolution": resolution,
        "semmap_ms": round(sem_ms, 2),
        "semmap_median_ms": round(sem_median, 2),
        "reference_ms": round(ref_ms, 2),
        "reference_median_ms": round(ref_median, 2),
        "vs_reference": round(sem_ms / ref_ms, 2),
        "vs_reference_median": round(sem_median / ref_median, 2),
        "reference_equal": bool(np.array_equal(ref_keys, c.packed) and np.array_equal(ref_logodds, c.logodds)),
        "octomap_ms": None if oct_ms is None else round(oct_ms, 2),
        "octomap_discretized_ms": round(oct_d_ms, 2),
        "speedup": None if oct_ms is None else round(oct_ms / sem_ms, 1),
        "speedup_vs_discretized": round(oct_d_ms / sem_ms, 1),
        "agreement": round(agree, 6),
        "reference_agreement": round(ref_agree, 6),
        "semmap_bytes_per_leaf": round(m.memory_bytes / max(m.num_leaves, 1), 1),
        "octomap_bytes_per_leaf": round(tree_d.memoryUsage() / max(tree_d.getNumLeafNodes(), 1), 1),
        "semmap_leaves": m.num_leaves,
        "octomap_leaves_expanded": int(o_keys.size),
        "semmap_stage_ms": {k: round(v, 2) for k, v in times["stages"].items()},
    }


def _print(case: str, r: dict) -> None:
    raw = f"OctoMap {r['octomap_ms']:.1f} ms (x{r['speedup']}) | " if r["octomap_ms"] is not None else ""
    print(f"{case} res {r['resolution']:.2f} m: semmap {r['semmap_ms']:.1f} ms/frame (median "
          f"{r['semmap_median_ms']:.1f}) | occupancy-only reference {r['reference_ms']:.1f} (median "
          f"{r['reference_median_ms']:.1f}): x{r['vs_reference']} (median x{r['vs_reference_median']}) | {raw}"
          f"OctoMap discretized {r['octomap_discretized_ms']:.1f} ms (x{r['speedup_vs_discretized']}) | agreement "
          f"{r['agreement']:.4%} (reference {r['reference_agreement']:.4%}, equal cells "
          f"{r['reference_equal']}) | bytes/leaf {r['semmap_bytes_per_leaf']} vs {r['octomap_bytes_per_leaf']} | "
          f"stages {r['semmap_stage_ms']}", file=sys.stderr)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="few frames, finishes in about a minute")
    ap.add_argument("--frames", type=int, default=None, help="consecutive-case frames (default 20, quick 4)")
    ap.add_argument("--stride", type=int, default=10, help="consecutive case: take every k-th frame")
    ap.add_argument("--sparse-frames", type=int, default=None, help="sparse-case frames (default 12, quick 4)")
    ap.add_argument("--sparse-stride", type=int, default=50, help="sparse case: take every k-th frame")
    ap.add_argument("--repeats", type=int, default=None, help="timed passes of semmap and the reference; each "
                    "frame's best counts (default 5, quick 2)")
    args = ap.parse_args()
    repeats = args.repeats or (2 if args.quick else 5)
    cases = {"consecutive": (args.frames or (4 if args.quick else 20), args.stride),
             "sparse": (args.sparse_frames or (4 if args.quick else 12), args.sparse_stride)}
    out: dict = {"bench": "octree_vs_octomap", "repeats": repeats}
    for case, (n, stride) in cases.items():
        source, frames = load_frames(n, stride)
        pts_per_frame = int(np.mean([len(p) for p, _, _ in frames]))
        print(f"{case}: {len(frames)} frames (every {stride}th) from {source}, {pts_per_frame} points per frame",
              file=sys.stderr)
        results = []
        for res in (0.05, 0.02):
            results.append(bench_resolution(frames, res, repeats=repeats, run_octomap_raw=case == "consecutive"))
            _print(case, results[-1])
        key = "results" if case == "consecutive" else "sparse_results"
        out.update({key: results} if case == "sparse" else
                   {"frames": len(frames), "points_per_frame": pts_per_frame, "source": source, key: results})
        if case == "sparse":
            out.update({"sparse_frames": len(frames), "sparse_stride": stride})
    print(json.dumps(out))


if __name__ == "__main__":
    main()
