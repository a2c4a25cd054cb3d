"""Simulator throughput: full frames (RGB, noisy depth, labels, instances) of the default scene at 640x480.

Renders with a ``--realism`` preset (default ``kinect``: every sensor effect on: the structured-light depth model
and the colour camera's blur, rolling shutter, exposure, noise and JPEG, with the camera's motion from the
neighbouring poses as ``semmap simulate`` renders them) and, in the same run, with ``clean`` (light depth noise,
the exact image); compares the default rasteriser backend with the open3d ray-casting
backend, and prints one JSON line last: {"bench": "sim", "realism": ..., "fps": ..., "fps_clean": ..., ...}.

    python benchmarks/bench_sim.py [--quick] [--realism kinect]
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from semmap.sim.realism import DEFAULT_REALISM, REALISMS, realism
from semmap.sim.render import Renderer
from semmap.sim.scene import generate_scene
from semmap.sim.trajectory import make_trajectory


def _fps_pair(a: Renderer, b: Renderer, poses: np.ndarray) -> tuple[float, float]:
    """Frames per second of ``a`` and of ``b``, rendering each pose with one then the other (so a busy machine's
    changing load falls on both alike)."""
    a.render_in(poses, 0)
    b.render_in(poses, 0)
    spent = [0.0, 0.0]
    for i in range(len(poses)):
        for k, r in enumerate((a, b)):
            start = time.perf_counter()
            r.render_in(poses, i)
            spent[k] += time.perf_counter() - start
    return len(poses) / spent[0], len(poses) / spent[1]


def _fps(renderer: Renderer, poses: np.ndarray) -> float:
    """Frames per second rendering all of ``poses`` (after one warm-up frame)."""
    renderer.render_in(poses, 0)
    start = time.perf_counter()
    for i in range(len(poses)):
        renderer.render_in(poses, i)
    return len(poses) / (time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--quick", action="store_true", help="fewer frames (for CI)")
    parser.add_argument("--realism", default="kinect", choices=REALISMS, help="the simulator's preset")
    args = parser.parse_args()
    n = 30 if args.quick else 150

    t0 = time.perf_counter()
    scene = generate_scene(0, "office", "medium")
    poses = make_trajectory(scene, "loop", n, seed=0)
    setup_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    preset, clean = realism(args.realism), realism(DEFAULT_REALISM)
    raster = Renderer(scene, noise=preset.depth_model(0), backend="raster", colour=preset.colour_camera(0))
    init_s = time.perf_counter() - t0
    raycast = Renderer(scene, noise=preset.depth_model(0), backend="raycast", colour=preset.colour_camera(0))
    fps, fps_clean = _fps_pair(raster, Renderer(scene, noise=clean.depth_model(0), colour=clean.colour_camera(0)),
                               poses)
    fps_raycast = _fps(raycast, poses[: max(10, n // 3)])
    cam = raster.intrinsics
    print(f"scene: {scene.n_triangles} triangles, {len(scene.objects)} objects, {len(scene.materials)} materials; "
          f"scene + trajectory {setup_s:.2f} s, renderer setup {init_s:.2f} s")
    print(f"raster backend : {fps:6.1f} frames/s ({1000 / fps:5.1f} ms/frame), realism {args.realism}")
    print(f"raster, {DEFAULT_REALISM:6} : {fps_clean:6.1f} frames/s ({1000 / fps_clean:5.1f} ms/frame)")
    print(f"raycast backend: {fps_raycast:6.1f} frames/s ({1000 / fps_raycast:5.1f} ms/frame)")
    print(json.dumps({"bench": "sim", "realism": args.realism, "fps": round(fps, 2), "fps_clean": round(fps_clean, 2),
                      "width": cam.width, "height": cam.height,
                      "frames": n, "backend": "raster", "fps_raycast": round(fps_raycast, 2),
                      "speedup_vs_raycast": round(fps / fps_raycast, 2), "triangles": scene.n_triangles}))


if __name__ == "__main__":
    main()
