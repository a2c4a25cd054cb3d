"""Semantic Monte-Carlo localization in simulated scenes: convergence, accuracy and speed, semantic vs geometry vs
the semantic-voxel-grid paper's cosine score (Sec. IV-C).

Each scene is mapped once with ground-truth poses and the cnn-like oracle segmenter (``semmap run``'s pipeline,
``map.semmap`` read back with ``semmap.localization.prior.load_prior`` as ``semmap localize`` does), then a
camera is localized along a different trajectory of the same scene (every 3rd frame of 30 frames/s: 10 updates per
second of motion; the frames segmented by the oracle with another seed; motion from the ground truth with 5 %
drift).  Global initialisation runs in ground mode (x, y, yaw; height and tilt known) and in 6-DoF; tracking
initialisation in 6-DoF.  Half of the scenes are symmetric rooms (``generate_scene(symmetric=True)``): their
geometry maps onto itself under a 180° turn and only the classes tell the halves apart.

The peer is the paper's method as it describes it: for each particle a local map of the frame is built in the
world and its voxel labels are compared with the map's (timed on a few particles with a per-particle loop over
the octree, and extrapolated); the ratio to semmap's update is printed.  Timings on a shared machine vary: the
best of the runs is reported next to the median.

    python benchmarks/bench_localization.py [--quick] [--out DIR]

Last line: {"bench": "localization", "results": [{"scene", "init", "model", "particles", "converged",
"frames_to_converge", "pos_err_m", "rot_err_deg", "ms_per_update"}...], ...}
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from semmap.config import InputConfig, MappingConfig, OutputConfig, RunConfig, SemanticsConfig
from semmap.datasets.simulated import SimulatedDataset
from semmap.localization.filter import FilterSettings
from semmap.localization.motion import GroundTilt, MotionMode, NoisyGroundTruth
from semmap.localization.observation import ObservationKind, make_scan
from semmap.localization.prior import PriorMap, load_prior
from semmap.localization.run import InitMode, localize
from semmap.perception.oracle import OracleSegmenter
from semmap.pipeline import Pipeline
from semmap.sim.scene import generate_scene
from semmap.sim.trajectory import make_trajectory
from semmap.types import DEFAULT_INTRINSICS, Frame

#: Camera of the benchmark: the simulator's 640x480 Kinect at half resolution (mapping and localization).
CAMERA = DEFAULT_INTRINSICS.scaled(0.5)
#: Mapping: a 20 s loop (1.25 laps of the room) rendered every MAP_STRIDE-th frame.
MAP_FRAMES, MAP_STRIDE = 600, 4
#: Localization: every 3rd frame of a 30 frames/s path = 10 updates per second of camera motion.
LOC_STRIDE = 3


@dataclass(frozen=True)
class SceneSpec:
    kind: str
    seed: int
    symmetric: bool

    @property
    def name(self) -> str:
        return f"{self.kind}-{self.seed}{'-symmetric' if self.symmetric else ''}"


FULL_SCENES = (SceneSpec("office", 0, False), SceneSpec("kitchen", 1, False), SceneSpec("living_room", 2, False),
               SceneSpec("bedroom", 3, False), SceneSpec("office", 0, True), SceneSpec("kitchen", 1, True),
               SceneSpec("bedroom", 2, True), SceneSpec("living_room", 3, True))
QUICK_SCENES = (SceneSpec("office", 0, False), SceneSpec("office", 0, True))


def build_map(spec: SceneSpec, out: Path, map_stride: int):
    """Map the scene along a loop with ground-truth poses and the cnn-like oracle (unless ``out`` holds its map
    already, from an earlier run with ``--out``); returns (scene, seconds)."""
    scene = generate_scene(spec.seed, spec.kind, "medium", symmetric=spec.symmetric)
    if (out / "map.semmap").is_file() and (out / "config.json").is_file():
        return scene, 0.0
    poses = make_trajectory(scene, "loop", MAP_FRAMES, seed=spec.seed)[::map_stride]
    if spec.symmetric:  # every other pose and its turned twin: the map covers both halves alike
        poses = np.concatenate([poses[::2], turned(scene) @ poses[::2]])
    ds = SimulatedDataset(scene, poses, seed=spec.seed, intrinsics=CAMERA, name=f"sim-{spec.name}")
    config = RunConfig(input=InputConfig(dataset=Path(ds.name)), mapping=MappingConfig(resolution=0.05),
                       semantics=SemanticsConfig(source="oracle"), output=OutputConfig(out=out))
    t = time.perf_counter()
    Pipeline(config, segmenter=OracleSegmenter(ds.label_set, preset="cnn-like", seed=spec.seed), dataset=ds).run()
    return scene, time.perf_counter() - t


def turned(scene) -> np.ndarray:
    """4x4 turn by 180° about the vertical line through the main room's centre (a symmetric room's symmetry)."""
    room = scene.rooms[0]
    centre = 0.5 * (room.bounds_min + room.bounds_max)
    T = np.diag([-1.0, -1.0, 1.0, 1.0])
    T[:2, 3] = 2.0 * centre[:2]
    return T


def localization_frames(scene, spec: SceneSpec, frames: int) -> list[Frame]:
    """Frames of another loop through the scene (another seed), every LOC_STRIDE-th, with oracle class sets."""
    poses = make_trajectory(scene, "loop", frames, seed=spec.seed + 1000)[::LOC_STRIDE]
    ds = SimulatedDataset(scene, poses, seed=spec.seed + 1000, intrinsics=CAMERA)
    seg = OracleSegmenter(ds.label_set, preset="cnn-like", seed=spec.seed + 1000)
    return [f.with_(semantics=seg.segment(f)) for f in ds]


def run_once(prior: PriorMap, frames: list[Frame], *, model: str, particles: int, init: str, mode: str,
             seed: int) -> dict:
    """One localization run; the benchmark's result row (plus diagnostics)."""
    settings = FilterSettings(particles=particles, mode=MotionMode(mode), model=ObservationKind(model))
    t = time.perf_counter()
    result = localize(prior, frames, NoisyGroundTruth(0.05, 0.05, seed=seed), settings=settings, init=InitMode(init),
                      segment=lambda f: f.semantics, tilt_of=lambda f: GroundTilt.from_pose(f.T_world_cam),
                      seed=seed, snapshot_every=0)
    s = result.summary()
    converged = bool(s.get("converged_to_truth", False))
    after_p = s.get("pos_err_m_after_convergence", {}).get("median")
    after_r = s.get("rot_err_deg_after_convergence", {}).get("median")
    return {"init": init, "mode": mode, "model": model, "particles": particles, "seed": seed,
            "converged": converged, "frames_to_converge": s["frames_to_converge"] if converged else None,
            "false_convergence": s["frames_to_converge"] is not None and not converged,
            "pos_err_m": after_p if converged else None, "rot_err_deg": after_r if converged else None,
            "ms_per_update": s["ms_per_update"]["median"], "ms_per_update_best": s["ms_per_update"]["min"],
            "cpu_ms_per_update": s["cpu_ms_per_update"]["median"],
            "updates": s["updates"], "seconds": round(time.perf_counter() - t, 1)}


def paper_style_ms(prior_map, prior: PriorMap, frame: Frame, particles: int = 8, seed: int = 0) -> float:
    """Milliseconds per particle of the paper's update as described: per particle, the frame's points placed in
    the world, a local voxel map built from them, the map's labels read at its voxels, cosine similarity."""
    from semmap.geometry import backproject_world

    rng = np.random.default_rng(seed)
    labels = frame.semantics.labels[..., 0].reshape(-1)
    T0 = frame.T_world_cam
    start = time.perf_counter()
    for _ in range(particles):
        T = T0.copy()
        T[:3, 3] += rng.normal(0, 0.1, 3)
        pts, pix = backproject_world(frame.depth, frame.intrinsics, T)
        cells = np.floor(pts / prior.resolution).astype(np.int64)
        _, first = np.unique(cells, axis=0, return_index=True)  # the local map's voxels
        local = labels[pix[first]].astype(np.float64)
        mapped = prior_map.semantics_at(pts[first]).labels[:, 0].astype(np.float64)
        mapped[mapped > 1000] = 0.0
        _ = float(local @ mapped / (np.linalg.norm(local) * np.linalg.norm(mapped) + 1e-12))
    return (time.perf_counter() - start) * 1e3 / particles


def scan_ms(prior: PriorMap, frames: list[Frame]) -> float:
    rng = np.random.default_rng(0)
    t = time.perf_counter()
    for f in frames[:10]:
        make_scan(f.depth, f.intrinsics, f.semantics, resolution=prior.resolution, rng=rng,
                  num_classes=prior.num_classes)
    return (time.perf_counter() - t) * 1e3 / min(10, len(frames))


def plan(quick: bool) -> list[dict]:
    """Runs per scene: (init, mode, model, particles, seeds).  The comparison of the three models at 2000 particles
    and the semantic model at 10000 run with three filter seeds in the full benchmark, the rest with one."""
    seeds = (0,) if quick else (0, 1, 2)
    one = (0,)
    runs = [{"init": "global", "mode": "ground", "model": m, "particles": 2000, "seeds": seeds}
            for m in ("semantic", "geometry", "cosine")]
    runs += [{"init": "global", "mode": "ground", "model": "semantic", "particles": 10000, "seeds": seeds}]
    if not quick:
        runs += [{"init": "global", "mode": "ground", "model": m, "particles": n, "seeds": one}
                 for m, n in (("semantic", 500), ("geometry", 10000), ("cosine", 10000))]
        runs += [{"init": "global", "mode": "6dof", "model": "semantic", "particles": 10000, "seeds": one}]
    runs += [{"init": "tracking", "mode": "6dof", "model": m, "particles": 2000, "seeds": one}
             for m in (("semantic",) if quick else ("semantic", "geometry", "cosine"))]
    if not quick:
        runs += [{"init": "tracking", "mode": "6dof", "model": "semantic", "particles": n, "seeds": one}
                 for n in (500, 10000)]
    return runs


def aggregate(rows: list[dict]) -> list[dict]:
    """Convergence rate, median frames to converge and errors per (scene kind, init, mode, model, particles)."""
    groups: dict[tuple, list[dict]] = {}
    for r in rows:
        key = ("symmetric" if r["scene"].endswith("symmetric") else "plain", r["init"], r["mode"], r["model"],
               r["particles"])
        groups.setdefault(key, []).append(r)
    out = []
    for (rooms, init, mode, model, n), rs in sorted(groups.items()):
        conv = [r for r in rs if r["converged"]]
        out.append({"rooms": rooms, "init": init, "mode": mode, "model": model, "particles": n, "runs": len(rs),
                    "converged_rate": round(len(conv) / len(rs), 3),
                    "false_convergences": sum(r["false_convergence"] for r in rs),
                    "median_frames_to_converge": _median([r["frames_to_converge"] for r in conv]),
                    "median_pos_err_m": _median([r["pos_err_m"] for r in conv]),
                    "median_rot_err_deg": _median([r["rot_err_deg"] for r in conv]),
                    "median_ms_per_update": _median([r["ms_per_update"] for r in rs]),
                    "median_cpu_ms_per_update": _median([r["cpu_ms_per_update"] for r in rs]),
                    "best_ms_per_update": min(r["ms_per_update_best"] for r in rs)})
    return out


def _median(values: list) -> float | None:
    v = [x for x in values if x is not None]
    return round(float(np.median(v)), 4) if v else None


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="2 scenes, one seed, fewer runs (under 10 minutes)")
    parser.add_argument("--out", type=Path, default=None, help="keep the maps here, and reuse those found there "
                        "(default: a temporary folder)")
    args = parser.parse_args()
    scenes = QUICK_SCENES if args.quick else FULL_SCENES
    loc_frames = 210 if args.quick else 300
    map_stride = 6 if args.quick else MAP_STRIDE
    t_start = time.perf_counter()
    rows: list[dict] = []
    peer: dict = {}
    with tempfile.TemporaryDirectory() as tmp:
        root = args.out or Path(tmp)
        for spec in scenes:
            scene, map_s = build_map(spec, root / spec.name, map_stride)
            t = time.perf_counter()
            prior = load_prior(root / spec.name / "map.semmap")
            prior_s = time.perf_counter() - t
            frames = localization_frames(scene, spec, loc_frames)
            print(f"{spec.name}: mapped in {map_s:.0f} s, lookup grids {prior_s:.1f} s "
                  f"({prior.describe()['grid_bytes'] / 2**20:.1f} MiB), {len(frames)} localization frames", flush=True)
            for run in plan(args.quick):
                for seed in run["seeds"]:
                    row = {"scene": spec.name, **run_once(prior, frames, model=run["model"],
                                                          particles=run["particles"], init=run["init"],
                                                          mode=run["mode"], seed=seed)}
                    rows.append(row)
                    print(f"  {row['init']:8s} {row['mode']:6s} {row['model']:8s} {row['particles']:6d} seed "
                          f"{seed}: converged {row['converged']!s:5s} after {row['frames_to_converge']} updates, "
                          f"error {row['pos_err_m']} m {row['rot_err_deg']} deg, {row['ms_per_update']} ms/update "
                          f"(best {row['ms_per_update_best']}, cpu {row['cpu_ms_per_update']})", flush=True)
            if not peer:
                from semmap.io.native import load_map

                per_particle = paper_style_ms(load_map(root / spec.name / "map.semmap"), prior, frames[0])
                peer = {"paper_style_ms_per_particle": round(per_particle, 2),
                        "scan_ms": round(scan_ms(prior, frames), 2)}
    summary = aggregate(rows)
    print("\nrooms      init     mode   model    particles  converged  frames  pos_err_m  rot_err_deg  ms/update "
          "(best; cpu ms)")
    for g in summary:
        print(f"{g['rooms']:10s} {g['init']:8s} {g['mode']:6s} {g['model']:8s} {g['particles']:9d}  "
              f"{g['converged_rate']:9.0%}  {g['median_frames_to_converge']!s:6s}  {g['median_pos_err_m']!s:9s}  "
              f"{g['median_rot_err_deg']!s:11s}  {g['median_ms_per_update']} ({g['best_ms_per_update']}; "
              f"{g['median_cpu_ms_per_update']})")
    for g in summary:
        if g["model"] == "semantic" and g["init"] == "global" and g["mode"] == "ground" and g["rooms"] == "plain" \
                and g["particles"] in (2000, 10000):
            n = g["particles"]
            ratio = peer["paper_style_ms_per_particle"] * n / g["best_ms_per_update"]
            print(f"{n} particles: the paper's per-particle local maps would take "
                  f"{peer['paper_style_ms_per_particle'] * n / 1e3:.0f} s per update; semmap {g['best_ms_per_update']} "
                  f"ms ({ratio:,.0f}x faster)")
            peer[f"speedup_vs_paper_style_{n}"] = round(ratio)
    print(json.dumps({"bench": "localization", "quick": args.quick, "results": [
        {k: r[k] for k in ("scene", "init", "model", "particles", "converged", "frames_to_converge", "pos_err_m",
                           "rot_err_deg", "ms_per_update")}
        | {"mode": r["mode"], "seed": r["seed"], "cpu_ms_per_update": r["cpu_ms_per_update"]} for r in rows],
        "summary": summary, "peer": peer, "seconds": round(time.perf_counter() - t_start, 1),
        "note": "wall-clock times on a machine shared with other jobs"}))


if __name__ == "__main__":
    main()
