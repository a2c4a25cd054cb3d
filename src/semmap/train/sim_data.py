"""The simulated scenes semmap's shipped networks learn from: the plans ``scripts/make_training_data.py`` renders
(training seeds 100-219, extra from 400, validation 300-307; the tests, benchmarks and demo use seeds 0-9), and
any planned scene's frames rendered in memory, as the replay that keeps an adapted network from forgetting
(:mod:`semmap.train.adapt`).

A scene is named ``{kind}-{size}-seed{seed}-{trajectory}`` (its folder in the training data and its entry in
``weights/manifest.json``); its frames are spread over ``PATH_SECONDS`` of the path, rendered at 640x480 by the
``clean`` preset and reduced to the training size as the segmenter reduces camera images."""

from __future__ import annotations

import re
from collections.abc import Iterator, Sequence
from typing import NamedTuple

import numpy as np

from semmap.errors import ConfigError, SimulationError
from semmap.sim.scene import KINDS, SIZES
from semmap.sim.trajectory import TRAJECTORY_KINDS
from semmap.types import Frame

TRAIN_SEEDS = range(100, 220)
#: Seeds of the extra training scenes of ``make_training_data.py --extra N`` (disjoint from the others).
EXTRA_SEEDS = range(400, 1000)
VAL_SEEDS = range(300, 308)
TRAIN_FRAMES, VAL_FRAMES = 17, 10
#: Seconds of camera motion the stored frames of a scene are spread over.
PATH_SECONDS = 20.0
#: The realism preset of every training and validation frame.
TRAINING_REALISM = "clean"
_NAME = re.compile(r"^(?P<kind>[a-z_]+)-(?P<size>[a-z]+)-seed(?P<seed>\d+)-(?P<trajectory>[a-z]+)$")


class PlannedScene(NamedTuple):
    """One simulated scene of a plan: generator seed, room kind, size and camera path (a tuple, as the scripts
    unpack it)."""

    seed: int
    kind: str
    size: str
    trajectory: str

    @property
    def name(self) -> str:
        return f"{self.kind}-{self.size}-seed{self.seed}-{self.trajectory}"

    @classmethod
    def parse(cls, name: str) -> PlannedScene:
        """The scene a name like ``office-small-seed100-desk`` stands for (ConfigError otherwise)."""
        m = _NAME.match(str(name))
        if (m is None or m["kind"] not in KINDS or m["size"] not in SIZES
                or m["trajectory"] not in TRAJECTORY_KINDS):
            raise ConfigError(f"{name!r} is not a simulated scene name (KIND-SIZE-seedN-TRAJECTORY, e.g. "
                              f"office-small-seed100-desk)")
        return cls(int(m["seed"]), m["kind"], m["size"], m["trajectory"])


def train_plan(seeds: Sequence[int] = TRAIN_SEEDS) -> list[PlannedScene]:
    """The training scenes of ``seeds``: every kind meets every trajectory kind and size (kind i % 4, trajectory
    (i + i // 4) % 4, size (i // 4) % 3)."""
    return [PlannedScene(seed, KINDS[i % 4], SIZES[(i // 4) % 3], TRAJECTORY_KINDS[(i + i // 4) % 4])
            for i, seed in enumerate(seeds)]


def val_plan() -> list[PlannedScene]:
    """The validation scenes: two per kind, medium, loop."""
    return [PlannedScene(seed, KINDS[i % 4], "medium", "loop") for i, seed in enumerate(VAL_SEEDS)]


def scene_frames(scene: PlannedScene, frames: int, *, picks: Sequence[int] | None = None,
                 image_size: tuple[int, int] | None = None, path_seconds: float = PATH_SECONDS) -> Iterator[Frame]:
    """Frames ``picks`` (default all) of the ``frames`` a planned scene's training data holds, rendered in memory
    as ``make_training_data.py`` writes them and reduced to ``image_size`` (width, height)."""
    from semmap.sim.export import reduce_frame, resized_intrinsics, simulate_frames
    from semmap.sim.realism import realism
    from semmap.sim.scene import generate_scene
    from semmap.sim.trajectory import make_trajectory

    preset = realism(TRAINING_REALISM)
    fps = frames / path_seconds
    built = generate_scene(scene.seed, scene.kind, scene.size)
    try:
        poses = make_trajectory(built, scene.trajectory, frames, seed=scene.seed, fps=fps, motion=preset.motion)
    except SimulationError:  # a desk / orbit path that does not fit the room: the loop, as the data script does
        poses = make_trajectory(built, "loop", frames, seed=scene.seed, fps=fps, motion=preset.motion)
    chosen = np.arange(frames) if picks is None else np.asarray(picks, np.int64)
    for frame in simulate_frames(built, poses[chosen], seed=scene.seed, fps=fps, realism=preset):
        if image_size is not None and (frame.intrinsics.width, frame.intrinsics.height) != tuple(image_size):
            frame = reduce_frame(frame, resized_intrinsics(frame.intrinsics, image_size))
        yield frame
