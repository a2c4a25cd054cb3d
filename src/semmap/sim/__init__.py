"""Built-in simulator: procedural indoor scenes rendered by ray casting / exact rasterisation, with ground truth.

Public API (imported lazily, so ``import semmap.sim`` stays cheap)::

    generate_scene(seed, kind="office", size="medium", second_room=None) -> Scene
    Renderer(scene, intrinsics=None, *, noise=False, seed=0, backend="raster").render(T_world_cam, frame_index=0)
        -> RenderedView(rgb, depth, labels, instances)
    KinectNoise(seed=0, ...).apply(depth, cos_incidence, frame_index)
    StructuredLight(seed=0, ...) / TimeOfFlight(...).apply_view(depth, cos_incidence, frame_index, fx=...)
    realism("clean" | "kinect" | "hard") -> Realism (depth model, colour, motion); REALISMS
    make_trajectory(scene, kind, n_frames, seed, fps=30.0, motion=None) -> (N, 4, 4) T_world_cam
    colour_params(preset) -> ColourParams (Renderer(colour=...));  motion_params(preset) -> MotionParams
    gt_voxels(scene, resolution) -> GroundTruthVoxels;  gt_objects(scene) -> list[SceneObject]
    simulate_sequence(out_dir, *, scene_seed=0, kind="office", trajectory="loop", frames=300, ...) -> Path
    INDOOR_LABELS
"""

from __future__ import annotations

import importlib

#: Module -> the public names it provides (read on first use).
_BY_MODULE = {
    "semmap.labels": ("INDOOR_LABELS",),
    "semmap.sim.scene": ("Scene", "SceneObject", "Room", "generate_scene", "KINDS", "SIZES"),
    "semmap.sim.render": ("Renderer", "RenderedView"),
    "semmap.types": ("DEFAULT_INTRINSICS",),
    "semmap.sim.noise": ("KinectNoise",),
    "semmap.sim.camera_model": ("ColourParams", "colour_params"),
    "semmap.sim.hand_motion": ("MotionParams", "motion_params"),
    "semmap.sim.depth_sensor": ("StructuredLight", "TimeOfFlight"),
    "semmap.sim.realism": ("Realism", "realism", "REALISMS"),
    "semmap.sim.trajectory": ("make_trajectory", "look_at", "TRAJECTORY_KINDS"),
    "semmap.sim.ground_truth": ("GroundTruthVoxels", "gt_voxels", "gt_objects"),
    "semmap.keys": ("coords_to_keys",),
    "semmap.sim.export": ("simulate_sequence", "simulate_frames"),
}
_EXPORTS = {name: module for module, names in _BY_MODULE.items() for name in names}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    if name in _EXPORTS:
        return getattr(importlib.import_module(_EXPORTS[name]), name)
    raise AttributeError(f"module 'semmap.sim' has no attribute {name!r}")
