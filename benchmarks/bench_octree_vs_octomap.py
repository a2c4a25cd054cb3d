"""semmap's SemanticOctoMap against the real OctoMap library (pyoctomap), same frames, same run.

Inserts the same back-projected RGB-D frames (7-Scenes from ../shared, or synthetic depth frames when absent)
into semmap (occupancy + colour + top-3 semantics) and into ``pyoctomap.OcTree.insertPointCloud`` with
``discretize=False`` and ``True``, at 0.05 m and 0.02 m.  Prints per-frame times, speed-up ratios, the
occupied / free / unknown agreement with OctoMap's discretized insert, and bytes per leaf; the last line is
one JSON object.

    python benchmarks/bench_octree_vs_octomap.py [--quick] [--frames N]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from semmap.geometry import backproject
from semmap.io.octomap_files import decode_octomap
from semmap.keys import pack_keys
from semmap.maps.semantic_octomap import SemanticOctoMap, compile_kernels
from semmap.types import CameraIntrinsics, TopKProbs, transform_points

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data" / "7scenes-redkitchen"


def load_frames(n: int, stride: int) -> tuple[str, list[tuple[np.ndarray, np.ndarray, np.ndarray]]]:
    """(source name, [(world points float64 (N,3), colours (N,3) uint8, origin (3,))])."""
    if SHARED.is_dir():
        from semmap.datasets import open_dataset

        out = []
        for f in open_dataset(SHARED, "7scenes", stride=stride, max_frames=n):
            pts, pix = backproject(f.depth, f.intrinsics)
            out.append((transform_points(f.T_world_cam, pts), f.rgb.reshape(-1, 3)[pix], f.T_world_cam[:3, 3]))
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


def bench_resolution(frames, resolution: float, run_octomap_raw: bool) -> dict:
    import pyoctomap

    compile_kernels()  # numba compiles (or loads) every kernel before anything is timed

    m = SemanticOctoMap(resolution)
    sem_times, stage_ms = [], {}
    for p, c, o in frames:
        sem = fake_semantics(c)
        t = time.perf_counter()
        st = m.insert_points(p, o, colors=c, semantics=sem)
        sem_times.append(time.perf_counter() - t)
        for k, v in st.ms.items():
            stage_ms[k] = stage_ms.get(k, 0.0) + v / len(frames)

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
    oct_ms = run_octomap(False)[1] if run_octomap_raw else float("nan")
    sem_ms = float(np.mean(sem_times) * 1e3)
    c = m.cells()
    o_keys, o_occ = octomap_states(tree_d, resolution)
    agree = agreement(c.packed, m.is_occupied(c.logodds), o_keys, o_occ)
    return {
        "resolution": resolution,
        "semmap_ms": round(sem_ms, 2),
        "octomap_ms": round(oct_ms, 2),
        "octomap_discretized_ms": round(oct_d_ms, 2),
        "speedup": round(oct_ms / sem_ms, 1),
        "speedup_vs_discretized": round(oct_d_ms / sem_ms, 1),
        "agreement": round(agree, 6),
        "semmap_bytes_per_leaf": round(m.memory_bytes / max(m.num_leaves, 1), 1),
        "octomap_bytes_per_leaf": round(tree_d.memoryUsage() / max(tree_d.getNumLeafNodes(), 1), 1),
        "semmap_leaves": m.num_leaves,
        "octomap_leaves_expanded": int(o_keys.size),
        "semmap_stage_ms": {k: round(v, 2) for k, v in stage_ms.items()},
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="few frames, finishes in under a minute")
    ap.add_argument("--frames", type=int, default=None, help="frames to insert (default 20, quick 4)")
    ap.add_argument("--stride", type=int, default=10, help="take every k-th frame of the sequence")
    args = ap.parse_args()
    n = args.frames or (4 if args.quick else 20)
    source, frames = load_frames(n, args.stride)
    pts_per_frame = int(np.mean([len(p) for p, _, _ in frames]))
    print(f"frames: {len(frames)} from {source}, {pts_per_frame} points per frame", file=sys.stderr)
    results = []
    for res in (0.05, 0.02):
        r = bench_resolution(frames, res, run_octomap_raw=True)
        results.append(r)
        print(f"res {res:.2f} m: semmap {r['semmap_ms']:.1f} ms/frame | OctoMap {r['octomap_ms']:.1f} ms "
              f"(x{r['speedup']}) | OctoMap discretized {r['octomap_discretized_ms']:.1f} ms "
              f"(x{r['speedup_vs_discretized']}) | agreement {r['agreement']:.4%} | bytes/leaf "
              f"{r['semmap_bytes_per_leaf']} vs {r['octomap_bytes_per_leaf']} | stages {r['semmap_stage_ms']}",
              file=sys.stderr)
    print(json.dumps({"bench": "octree_vs_octomap", "frames": len(frames), "points_per_frame": pts_per_frame,
                      "source": source, "results": results}))


if __name__ == "__main__":
    main()
