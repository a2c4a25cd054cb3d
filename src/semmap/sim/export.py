"""Simulate a whole sequence to disk as a TUM RGB-D folder with ground-truth labels, instances and objects.

Layout: ``rgb/``, ``depth/`` (16-bit PNG, metres x 5000, 0 invalid), ``labels/`` and ``instances/`` (uint16
PNG), ``rgb.txt``, ``depth.txt``, ``groundtruth.txt``, ``camera.json`` (written by
:func:`semmap.io.tum_writer.write_tum_sequence`), plus ``labelset.json``, ``objects.json`` and
``scene.json`` (generator parameters, trajectory kind, frame count, seeds). Timestamps start at 0 and advance
by 1/30 s; frames are rendered and written one at a time, so memory stays bounded.

``image_size`` stores smaller frames (e.g. 160x120 training data for ``semmap train``): each frame is rendered
at the camera's full size and then reduced the way a network's input is (colour by pixel-area averaging,
depth, labels and instances by nearest neighbour), with the intrinsics scaled to match.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Callable, Iterable, Iterator, Sequence
from pathlib import Path

import cv2
import numpy as np

from semmap.errors import OutputError, SimulationError
from semmap.files.atomic import write_text_atomic
from semmap.files.outputs import OutputKind, check_outputs
from semmap.interrupt import RunInterrupted
from semmap.io.benchmark_layouts import write_replica_scene, write_scannet_scan
from semmap.io.staged_run import StagedRun
from semmap.io.tum_writer import write_tum_sequence
from semmap.labels import INDOOR_LABELS, NYU40_NAMES, simulator_to_nyu40
from semmap.limits import check, check_simulation
from semmap.sim.camera_model import ColourParams
from semmap.sim.changes import change_scene
from semmap.sim.hand_motion import MotionParams
from semmap.sim.people import Walker, add_people
from semmap.sim.realism import Realism, realism
from semmap.sim.render import Renderer
from semmap.sim.scene import Scene, generate_scene
from semmap.sim.trajectory import make_trajectory
from semmap.types import DEFAULT_INTRINSICS, CameraIntrinsics, Frame

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
    image_size: tuple[int, int] | None = None,
    fps: float = FPS,
    symmetric: bool = False,
    trajectory_seed: int | None = None,
    layout: str = "tum",
    changes: int = 0,
    changes_seed: int = 1,
    colour: ColourParams | None = None,
    motion: MotionParams | None = None,
    people: int = 0,
    realism: str | Realism | None = None,
) -> Path:
    """Render ``frames`` frames of a ``trajectory`` through scene (``scene_seed``, ``kind``, ``size``;
    ``symmetric``: see :mod:`semmap.sim.symmetric`) into ``out_dir`` (TUM layout plus ground truth) and return the
    folder; the path is drawn from ``trajectory_seed`` (default: the scene seed). Same arguments, same bytes. A low
    ``fps`` spreads few frames over the whole path (varied views for training data). ``realism`` names the
    preset of :mod:`semmap.sim.realism` (default ``clean``: today's frames; scene.json records it): its depth
    sensor, colour camera and hand-held motion; ``colour`` and ``motion`` override the preset's
    (:mod:`semmap.sim.camera_model`, :mod:`semmap.sim.hand_motion`). ``people`` walk through the scene
    (:mod:`semmap.sim.people`; labelled ``person``, left out of the 3D ground truth and ``objects.json``)."""
    if not isinstance(frames, (int, np.integer)) or frames <= 0:
        raise SimulationError(f"frames must be a positive integer, got {frames!r}")
    check_simulation(int(frames), image_size)
    if layout not in LAYOUTS:
        raise SimulationError(f"unknown layout {layout!r}; choose one of {', '.join(LAYOUTS)}")
    check("seed", scene_seed, "--scene-seed")
    check("seed", trajectory_seed, "--trajectory-seed")
    check("seed", changes_seed, "--changes-seed")
    check("people", people, "--people")
    preset = realism_of(realism, noise)
    if image_size is not None:
        check_reduced_size(image_size, intrinsics or DEFAULT_INTRINSICS)
    root = Path(out_dir)
    check_sequence_out(root)
    staged = StagedRun(root)
    stage = staged.open()
    try:
        _write_sequence(stage, scene_seed=scene_seed, kind=kind, trajectory=trajectory, frames=int(frames), size=size,
                        noise=noise, intrinsics=intrinsics, progress=progress, image_size=image_size, fps=fps,
                        symmetric=symmetric, trajectory_seed=trajectory_seed, layout=layout,
                        changes=(changes, changes_seed), colour=colour or preset.colour_camera(scene_seed),
                        motion=motion or preset.motion, people=int(people), preset=preset)
        staged.commit()  # every file is there: the folder becomes ``out_dir`` in one rename
    except KeyboardInterrupt:
        staged.abandon(keep_checkpoint=False)  # Ctrl-C leaves nothing half-written, and says so
        raise RunInterrupted(f"interrupted while rendering; nothing written to {root}") from None
    except BaseException:
        staged.abandon(keep_checkpoint=False)  # nor does a failure or a full disk
        raise
    return root


def check_sequence_out(root: Path) -> None:
    """``--out`` of a simulation: a new or empty folder, or an earlier simulated sequence (it has ``scene.json``)
    replaced as a whole; a folder holding anything else (a run, another sequence) is refused, never mixed."""
    check_outputs([("--out", root, OutputKind.FOLDER)], [])
    if root.is_dir() and any(root.iterdir()) and not (root / "scene.json").is_file():
        raise OutputError(f"--out {root}: holds other files (not a sequence written by semmap simulate); choose a "
                          f"new or empty folder (nothing was written)")


def _write_sequence(root: Path, *, scene_seed: int, kind: str, trajectory: str, frames: int, size: str, noise: bool,
                    intrinsics: CameraIntrinsics | None, progress: Callable[[int, int], None] | None,
                    image_size: tuple[int, int] | None, fps: float, symmetric: bool,
                    trajectory_seed: int | None, layout: str = "tum", changes: tuple[int, int] = (0, 1),
                    colour: ColourParams | None = None, motion: MotionParams | None = None,
                    people: int = 0, preset: Realism | None = None) -> None:
    """Render and write the whole sequence into the folder ``root`` (the staging folder)."""
    scene = generate_scene(scene_seed, kind, size, symmetric=symmetric)
    walked = scene  # the camera walks the path of the scene as it was, so both recordings see the same views
    if changes[0]:
        scene, record = change_scene(scene, changes[0], changes[1])
        write_text_atomic(root / "changes.json", json.dumps(record, indent=1) + "\n")
    poses = make_trajectory(walked, trajectory, int(frames), seed=scene_seed if trajectory_seed is None
                            else trajectory_seed, fps=fps, motion=motion)
    preset = preset or realism()
    shown, walkers = add_people(scene, people, scene_seed, poses[:, :3, 3], fps)  # (the scene stays static)
    renderer = Renderer(shown, intrinsics, noise=preset.depth_model(scene_seed, noise) or False, colour=colour)
    frames_out = render_frames(renderer, poses, progress, fps=fps, walkers=walkers)
    stored = renderer.intrinsics
    if image_size is not None:
        stored = resized_intrinsics(renderer.intrinsics, image_size)
        frames_out = (reduce_frame(f, stored) for f in frames_out)
    _write_frames(root, frames_out, layout)
    write_text_atomic(root / "objects.json", json.dumps([o.to_dict() for o in scene.objects], indent=1) + "\n")
    info = {**scene.params, "trajectory": trajectory, "frames": int(frames), "fps": fps, "noise": bool(noise),
            "depth_scale": DEPTH_SCALE, "intrinsics": stored.to_dict(),
            "n_triangles": scene.n_triangles, "n_objects": len(scene.objects), "layout": layout,
            "realism": preset.name}
    if layout == "scannet":
        info["label_space"] = "nyu40"  # the 3D ground truth's classes are mapped like the frames' labels
    if trajectory_seed is not None:
        info["trajectory_seed"] = int(trajectory_seed)
    info.update(camera_info(colour, motion))
    if people:
        info["people"] = [{"id": w.instance_id, "class": "person", "path": np.round(w.path, 4).tolist(),
                           "phase_m": round(w.phase, 4), "speed_mps": w.speed} for w in walkers]
    write_text_atomic(root / "scene.json", json.dumps(info, indent=1) + "\n")


#: Layouts ``semmap simulate --format`` writes: TUM RGB-D (semmap's own), a ScanNet scan, Replica (NICE-SLAM).
LAYOUTS = ("tum", "scannet", "replica")


def _write_frames(root: Path, frames: Iterable[Frame], layout: str) -> None:
    """The frames and their labels in ``layout``."""
    if layout == "scannet":
        write_scannet_scan(root, frames, INDOOR_LABELS, simulator_to_nyu40(), NYU40_NAMES)
    elif layout == "replica":
        write_replica_scene(root, frames, INDOOR_LABELS)
    else:
        write_tum_sequence(root, frames, depth_scale=DEPTH_SCALE, write_labels=True)
        INDOOR_LABELS.save(root / "labelset.json")


def check_reduced_size(size: tuple[int, int], native: CameraIntrinsics) -> None:
    """``--image-size`` only reduces the rendered frames (as its help says): a side above the camera's is refused
    in one line naming the native size, before anything is rendered or allocated."""
    w, h = int(size[0]), int(size[1])
    if w > native.width or h > native.height:
        raise SimulationError(f"--image-size {w}x{h} is larger than the native {native.width}x{native.height} the "
                              f"frames are rendered at; it only reduces them (e.g. 160x120)")


def resized_intrinsics(intrinsics: CameraIntrinsics, size: tuple[int, int]) -> CameraIntrinsics:
    """Intrinsics of images resized to ``size`` (width, height), pixel-centre convention per axis."""
    w, h = int(size[0]), int(size[1])
    if w < 8 or h < 8:
        raise SimulationError(f"image size must be at least 8x8, got {w}x{h}")
    sx, sy = w / intrinsics.width, h / intrinsics.height
    return CameraIntrinsics(w, h, intrinsics.fx * sx, intrinsics.fy * sy, (intrinsics.cx + 0.5) * sx - 0.5,
                            (intrinsics.cy + 0.5) * sy - 0.5)


def reduce_frame(frame: Frame, intrinsics: CameraIntrinsics) -> Frame:
    """``frame`` resized to ``intrinsics``' size: colour area-averaged, depth and id images nearest-neighbour
    (no blending of depths across edges, no invented class ids)."""
    size = (intrinsics.width, intrinsics.height)

    def nearest(a: np.ndarray | None) -> np.ndarray | None:
        return None if a is None else cv2.resize(a, size, interpolation=cv2.INTER_NEAREST)

    instances = None if frame.instances is None else nearest(frame.instances.astype(np.float32)).astype(np.int32)
    return frame.with_(rgb=cv2.resize(frame.rgb, size, interpolation=cv2.INTER_AREA), depth=nearest(frame.depth),
                       labels=nearest(frame.labels), instances=instances, intrinsics=intrinsics)


def render_frames(renderer: Renderer, poses: np.ndarray, progress: Callable[[int, int], None] | None = None,
                  fps: float = FPS, walkers: Sequence[Walker] = ()) -> Iterator[Frame]:
    """Frames (rgb, depth, labels, instances, pose) rendered lazily along ``poses`` at ``fps`` frames/s, the
    ``walkers`` (:mod:`semmap.sim.people`) where they are at each frame's time."""
    n = len(poses)
    for i, T in enumerate(poses):
        for w in walkers:
            renderer.move(w.first_vertex, w.vertices_at(i / fps), w.triangles)
        view = renderer.render_in(poses, i, fps)
        stamp = i / fps
        yield Frame(index=i, timestamp=stamp, rgb=view.rgb, depth=view.depth, intrinsics=renderer.intrinsics,
                    T_world_cam=np.asarray(T, np.float64), labels=view.labels, instances=view.instances,
                    name=f"{stamp:.6f}")
        if progress is not None:
            progress(i + 1, n)


def simulate_frames(scene: Scene, poses: np.ndarray, *, noise: bool = True, seed: int = 0,
                    intrinsics: CameraIntrinsics | None = None, colour: ColourParams | None = None,
                    people: int = 0, fps: float = FPS, realism: str | Realism | None = None) -> Iterator[Frame]:
    """In-memory counterpart of :func:`simulate_sequence` for a given scene and poses (no files), with ``people``
    walking through it (seeded by ``seed``) and the ``realism`` preset's sensors (``colour`` overrides its camera)."""
    preset = realism_of(realism, noise)
    scene, walkers = add_people(scene, people, seed, np.asarray(poses)[:, :3, 3], fps)
    renderer = Renderer(scene, intrinsics, noise=preset.depth_model(seed, noise) or False,
                        colour=colour or preset.colour_camera(seed))
    yield from render_frames(renderer, poses, fps=fps, walkers=walkers)


def camera_info(colour: ColourParams | None, motion: MotionParams | None) -> dict:
    """``scene.json`` entries naming the colour camera and hand motion used (none for the clean defaults, so a
    clean sequence's files stay as they were)."""
    info: dict = {}
    if colour is not None and not colour.is_clean:
        info["colour_camera"] = dataclasses.asdict(colour)
    if motion is not None and motion.hand:
        info["hand_motion"] = dataclasses.asdict(motion)
    return info


def realism_of(name: str | Realism | None, noise: bool = True) -> Realism:
    """The realism preset ``name``; exact depth (``noise`` off) is only offered with ``clean``, whose frames
    are today's: the other presets are their sensor, and a noiseless one would be neither."""
    preset = realism(name)
    if not noise and not preset.exact_geometry:
        raise SimulationError(f"--no-noise works only with --realism clean; --realism {preset.name} simulates a "
                              f"real sensor's depth")
    return preset
