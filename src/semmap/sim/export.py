"""Simulate a whole sequence to disk as a TUM RGB-D folder with ground-truth labels, instances and objects.

Layout: ``rgb/``, ``depth/`` (16-bit PNG, metres x 5000, 0 invalid), ``labels/`` and ``instances/`` (uint16
PNG), ``rgb.txt``, ``depth.txt``, ``groundtruth.txt``, ``camera.json`` (written by
:func:`semmap.datasets.tum_writer.write_tum_sequence`), plus ``labelset.json``, ``objects.json`` and
``scene.json`` (generator parameters, trajectory kind, frame count, seeds). Timestamps start at 0 and advance
by 1/30 s; frames are rendered and written one at a time, so memory stays bounded.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np

from semmap.datasets.tum_writer import write_tum_sequence
from semmap.errors import SimulationError
from semmap.io.atomic import write_text_atomic
from semmap.sim.labels import INDOOR_LABELS
from semmap.sim.noise import KinectNoise
from semmap.sim.render import Renderer
from semmap.sim.scene import Scene, generate_scene
from semmap.sim.trajectory import make_trajectory
from semmap.types import CameraIntrinsics, Frame

FPS = 30.0
DEPTH_SCALE = 5000.0


def simulate_sequence(
    out_dir: str | Path,
    *,
    scene_seed: int = 0,
    kind: str = "office",
    trajectory: str = "loop",
    frames: int = 300,
    size: str = "medium",
    noise: bool = True,
    intrinsics: CameraIntrinsics | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> Path:
    """Render ``frames`` frames of a ``trajectory`` through scene (``scene_seed``, ``kind``, ``size``) into
    ``out_dir`` (TUM layout plus ground truth) and return the folder. Same arguments, same bytes."""
    if not isinstance(frames, (int, np.integer)) or frames <= 0:
        raise SimulationError(f"frames must be a positive integer, got {frames!r}")
    root = Path(out_dir)
    root.mkdir(parents=True, exist_ok=True)
    scene = generate_scene(scene_seed, kind, size)
    poses = make_trajectory(scene, trajectory, int(frames), seed=scene_seed, fps=FPS)
    renderer = Renderer(scene, intrinsics, noise=KinectNoise(seed=scene_seed) if noise else False)
    write_tum_sequence(root, render_frames(renderer, poses, progress), depth_scale=DEPTH_SCALE, write_labels=True)
    INDOOR_LABELS.save(root / "labelset.json")
    write_text_atomic(root / "objects.json", json.dumps([o.to_dict() for o in scene.objects], indent=1) + "\n")
    info = {**scene.params, "trajectory": trajectory, "frames": int(frames), "fps": FPS, "noise": bool(noise),
            "depth_scale": DEPTH_SCALE, "intrinsics": renderer.intrinsics.to_dict(),
            "n_triangles": scene.n_triangles, "n_objects": len(scene.objects)}
    write_text_atomic(root / "scene.json", json.dumps(info, indent=1) + "\n")
    return root


def render_frames(renderer: Renderer, poses: np.ndarray,
                  progress: Callable[[int, int], None] | None = None) -> Iterator[Frame]:
    """Frames (rgb, depth, labels, instances, pose) rendered lazily along ``poses`` at 30 frames/s."""
    n = len(poses)
    for i, T in enumerate(poses):
        view = renderer.render(T, frame_index=i)
        stamp = i / FPS
        yield Frame(index=i, timestamp=stamp, rgb=view.rgb, depth=view.depth, intrinsics=renderer.intrinsics,
                    T_world_cam=np.asarray(T, np.float64), labels=view.labels, instances=view.instances,
                    name=f"{stamp:.6f}")
        if progress is not None:
            progress(i + 1, n)


def simulate_frames(scene: Scene, poses: np.ndarray, *, noise: bool = True, seed: int = 0,
                    intrinsics: CameraIntrinsics | None = None) -> Iterator[Frame]:
    """In-memory counterpart of :func:`simulate_sequence` for a given scene and poses (no files)."""
    renderer = Renderer(scene, intrinsics, noise=KinectNoise(seed=seed) if noise else False)
    yield from render_frames(renderer, poses)
