"""Built-in simulator: procedural indoor scenes rendered by ray casting / exact rasterisation, with ground truth.

Public API (imported lazily, so ``import semmap.sim`` stays cheap)::

    generate_scene(seed, kind="office", size="medium", second_room=None) -> Scene
    Renderer(scene, intrinsics=None, *, noise=False, seed=0, backend="raster").render(T_world_cam, frame_index=0)
        -> RenderedView(rgb, depth, labels, instances)
    KinectNoise(seed=0, ...).apply(depth, cos_incidence, frame_index)
    make_trajectory(scene, kind, n_frames, seed, fps=30.0) -> (N, 4, 4) T_world_cam
    gt_voxels(scene, resolution) -> GroundTruthVoxels;  gt_objects(scene) -> list[SceneObject]
    simulate_sequence(out_dir, *, scene_seed=0, kind="office", trajectory="loop", frames=300, ...) -> Path
    INDOOR_LABELS
"""

from __future__ import annotations

import importlib

_EXPORTS = {
    "INDOOR_LABELS": "semmap.labels",
    "Scene": "semmap.sim.scene",
    "SceneObject": "semmap.sim.scene",
    "Room": "semmap.sim.scene",
    "generate_scene": "semmap.sim.scene",
    "KINDS": "semmap.sim.scene",
    "SIZES": "semmap.sim.scene",
    "Renderer": "semmap.sim.render",
    "RenderedView": "semmap.sim.render",
    "DEFAULT_INTRINSICS": "semmap.types",
    "KinectNoise": "semmap.sim.noise",
    "make_trajectory": "semmap.sim.trajectory",
    "look_at": "semmap.sim.trajectory",
    "TRAJECTORY_KINDS": "semmap.sim.trajectory",
    "GroundTruthVoxels": "semmap.sim.ground_truth",
    "gt_voxels": "semmap.sim.ground_truth",
    "gt_objects": "semmap.sim.ground_truth",
    "coords_to_keys": "semmap.keys",
    "simulate_sequence": "semmap.sim.export",
    "simulate_frames": "semmap.sim.export",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    if name in _EXPORTS:
        return getattr(importlib.import_module(_EXPORTS[name]), name)
    raise AttributeError(f"module 'semmap.sim' has no attribute {name!r}")
