"""The built-in simulator as a dataset: frames rendered on the fly from a procedural scene, no files."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np

from semmap.datasets.base import SkippedFrame
from semmap.labels import INDOOR_LABELS
from semmap.sim.camera_model import ColourParams
from semmap.sim.export import realism_of, simulate_frames
from semmap.sim.hand_motion import MotionParams
from semmap.sim.scene import Scene, generate_scene
from semmap.sim.trajectory import make_trajectory
from semmap.types import DEFAULT_INTRINSICS, CameraIntrinsics, Frame, LabelSet


class SimulatedDataset:
    """Frames (rgb, depth, labels, instances, ground-truth pose) of ``poses`` through ``scene``, rendered lazily
    (``colour``: the colour camera, :mod:`semmap.sim.camera_model`; default clean)."""

    def __init__(self, scene: Scene, poses: np.ndarray, *, noise: bool = True, seed: int = 0,
                 intrinsics: CameraIntrinsics | None = None, name: str = "simulated",
                 colour: ColourParams | None = None, people: int = 0, fps: float = 30.0,
                 realism: str | None = None) -> None:
        self.scene = scene  # the static scene (walking ``people`` are rendered, never part of it)
        self.people, self.fps = int(people), float(fps)
        #: the realism preset the frames are rendered with (semmap.sim.realism)
        self.realism = realism_of(realism, noise).name
        self.poses = np.asarray(poses, np.float64)
        self.noise = noise
        self.seed = seed
        self._intrinsics = intrinsics or DEFAULT_INTRINSICS
        self._name = name
        self.colour = colour

    @classmethod
    def default(cls, *, scene_seed: int = 0, kind: str = "office", size: str = "medium", trajectory: str = "loop",
                frames: int = 300, noise: bool = True, colour: ColourParams | None = None,
                motion: MotionParams | None = None, realism: str | None = None) -> SimulatedDataset:
        """The default scene and trajectory (what ``semmap demo`` maps); ``colour``, ``motion`` and ``realism`` as
        in :func:`semmap.sim.export.simulate_sequence` (default: clean)."""
        preset = realism_of(realism, noise)
        scene = generate_scene(scene_seed, kind, size)
        poses = make_trajectory(scene, trajectory, frames, seed=scene_seed, motion=motion or preset.motion)
        return cls(scene, poses, noise=noise, seed=scene_seed, name=f"sim-{kind}-{size}-seed{scene_seed}-{trajectory}",
                   colour=colour, realism=preset.name)

    @property
    def name(self) -> str:
        return self._name

    @property
    def intrinsics(self) -> CameraIntrinsics:
        return self._intrinsics

    @property
    def label_set(self) -> LabelSet:
        return INDOOR_LABELS

    @property
    def skipped(self) -> list[SkippedFrame]:
        return []

    def __len__(self) -> int:
        return len(self.poses)

    def __iter__(self) -> Iterator[Frame]:
        yield from simulate_frames(self.scene, self.poses, noise=self.noise, seed=self.seed,
                                   intrinsics=self._intrinsics, colour=self.colour, people=self.people, fps=self.fps,
                                   realism=self.realism)


def scene_of_folder(root) -> Scene | None:
    """The scene a folder written by ``semmap simulate`` was rendered from (regenerated from its
    ``scene.json``), or None when the folder is not a simulator export or the generator has changed since."""
    import json
    import logging
    from pathlib import Path

    path = Path(root) / "scene.json"
    if not path.is_file():
        return None
    log = logging.getLogger("semmap")
    from semmap.errors import SemmapError
    from semmap.files.safe import read_text_limited
    from semmap.sim.changes import change_scene

    try:
        info = json.loads(read_text_limited(path, what="scene description"))
        scene = generate_scene(int(info["seed"]), str(info["kind"]), str(info["size"]),
                               symmetric=bool(info.get("symmetric", False)))
        if info.get("changes"):
            scene, _ = change_scene(scene, int(info["changes"]), int(info.get("changes_seed", 1)))
    except (SemmapError, ValueError, KeyError, TypeError, AttributeError) as exc:
        log.warning("%s: cannot regenerate the simulated scene (%s); no 3D ground truth", path, exc)
        return None
    same = all(scene.params.get(k) == info.get(k) for k in ("generator_version", "second_room", "rooms"))
    if not same or scene.n_triangles != info.get("n_triangles"):
        log.warning("%s: written by another scene generator version; no 3D ground truth", path)
        return None
    return scene

