"""Replay: some of a network's original training data, mixed into every adaptation step so that the network learns
the new scene without forgetting the old ones (and the original validation scenes, to watch that it does not).

Where the data comes from, first found wins: data folders the user names (``--replay``, as ``semmap train
--data`` takes them); the plan a weight file records (``meta.replay``: what an earlier adaptation replayed);
the scenes of ``weights/manifest.json`` when the weights are a shipped network's (or were adapted from one); the
training folders of a user's own ``semmap train`` run, when they still exist. Simulated scenes are rendered in
memory (:func:`semmap.train.sim_data.scene_frames`) and kept in ``$SEMMAP_CACHE_DIR/replay`` (default
``~/.cache/semmap/replay``): the second adaptation of the same network reads them back."""

from __future__ import annotations

import hashlib
import io
import json
import logging
import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from semmap.errors import ConfigError, FormatError
from semmap.train.data import DEPTH_MM, TrainingSet, gather
from semmap.train.sim_data import PATH_SECONDS, PlannedScene, scene_frames, val_plan
from semmap.types import LabelSet

log = logging.getLogger("semmap")

#: Simulated scenes replayed (spread evenly over the plan) and frames of each (spread over its frames).
REPLAY_SCENES, REPLAY_FRAMES = 32, 4
#: Validation images that watch forgetting: frames of each original validation scene.
VAL_FRAMES_PER_SCENE = 3
#: Images taken from replay folders (spread evenly over them).
REPLAY_FOLDER_IMAGES = 128


@dataclass(frozen=True)
class ReplayPlan:
    """Simulated scenes to replay (``scenes``, ``frames`` stored per scene over ``path_seconds``) and validation
    scenes (``val_scenes``, ``val_frames`` each) to measure forgetting on."""

    scenes: tuple[PlannedScene, ...]
    frames: int
    path_seconds: float = PATH_SECONDS
    val_scenes: tuple[PlannedScene, ...] = ()
    val_frames: int = 10
    source: str = ""

    def to_dict(self) -> dict:
        return {"scenes": [s.name for s in self.scenes], "frames_per_scene": self.frames,
                "path_seconds": self.path_seconds, "val_scenes": [s.name for s in self.val_scenes],
                "val_frames_per_scene": self.val_frames}

    @classmethod
    def from_dict(cls, d: dict, source: str) -> ReplayPlan:
        """The plan a manifest's ``data.train`` / a weight file's ``meta.replay`` records (FormatError naming
        ``source`` otherwise)."""
        try:
            scenes = tuple(PlannedScene.parse(n) for n in d["scenes"])
            val = tuple(PlannedScene.parse(n) for n in d.get("val_scenes", ()))
            return cls(scenes, int(d["frames_per_scene"]), float(d.get("path_seconds", PATH_SECONDS)), val,
                       int(d.get("val_frames_per_scene", 10)), source)
        except (KeyError, TypeError, ValueError, ConfigError) as exc:
            raise FormatError(f"{source}: unreadable replay plan ({exc})") from None


def manifest_plan(manifest: dict, source: str) -> ReplayPlan:
    """The replay plan of a shipped-weights manifest: its training scenes, and its validation seeds as
    :func:`~semmap.train.sim_data.val_plan` names them."""
    try:
        train, val = manifest["data"]["train"], manifest["data"].get("val", {})
        seeds = {int(s) for s in val.get("scene_seeds", ())}
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise FormatError(f"{source}: no training scenes in the manifest ({exc})") from None
    plan = ReplayPlan.from_dict(train, source)
    val_scenes = tuple(s for s in val_plan() if s.seed in seeds)
    return ReplayPlan(plan.scenes, plan.frames, plan.path_seconds, val_scenes, int(val.get("frames_per_scene", 10)),
                      source)


def evenly(n: int, k: int) -> list[int]:
    """``k`` indices spread evenly over ``range(n)`` (all of them when ``k >= n``)."""
    if k >= n:
        return list(range(n))
    return sorted({int(i) for i in np.linspace(0, n - 1, k).round()})


def balanced(plan: Sequence[PlannedScene], n: int) -> list[PlannedScene]:
    """``n`` scenes of ``plan``, as many of each room kind as can be, spread evenly over each kind's scenes."""
    kinds = list(dict.fromkeys(s.kind for s in plan))
    groups = {k: [s for s in plan if s.kind == k] for k in kinds}
    share = {k: n // len(kinds) + (i < n % len(kinds)) for i, k in enumerate(kinds)}
    picked = {k: [groups[k][i] for i in evenly(len(groups[k]), share[k])] for k in kinds}
    order = [s for rank in range(max(map(len, picked.values()), default=0)) for k in kinds
             if rank < len(picked[k]) for s in (picked[k][rank],)]
    return order


def cache_dir() -> Path:
    """``$SEMMAP_CACHE_DIR/replay`` (default ``~/.cache/semmap/replay``)."""
    return Path(os.environ.get("SEMMAP_CACHE_DIR", Path.home() / ".cache" / "semmap")) / "replay"


def render_scenes(scenes: Sequence[PlannedScene], frames: int, picks: Sequence[int], size: tuple[int, int],
                  label_set: LabelSet, *, path_seconds: float = PATH_SECONDS, cache: Path | None = None
                  ) -> TrainingSet:
    """Frames ``picks`` of each scene's ``frames`` rendered at 640x480 and reduced to ``size`` (width, height), as
    a training set; read from / written to ``cache`` (a folder) when given."""
    key = hashlib.sha1(json.dumps([[s.name for s in scenes], frames, list(picks), list(size), path_seconds,
                                   list(label_set.names)]).encode()).hexdigest()[:16]
    path = None if cache is None else cache / f"replay-{key}.npz"
    if path is not None and path.is_file():
        try:
            with np.load(path) as z:
                return TrainingSet(z["rgb"], z["labels"], z["depth"], label_set, [str(path)] * len(z["rgb"]))
        except (OSError, ValueError, KeyError) as exc:
            log.warning("%s: unreadable replay cache (%s); rendering again", path, type(exc).__name__)
    w, h = size
    n = len(scenes) * len(picks)
    rgb = np.empty((n, h, w, 3), np.uint8)
    labels = np.empty((n, h, w), np.uint16)
    depth = np.empty((n, h, w), np.uint16)
    i = 0
    for scene in scenes:
        for frame in scene_frames(scene, frames, picks=picks, image_size=size, path_seconds=path_seconds):
            rgb[i], labels[i] = frame.rgb, frame.labels
            depth[i] = np.clip(np.rint(np.nan_to_num(frame.depth) * DEPTH_MM), 0, 65535)
            i += 1
    if path is not None:
        from semmap.files.atomic import write_bytes_atomic

        buf = io.BytesIO()
        np.savez(buf, rgb=rgb, labels=labels, depth=depth)
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            write_bytes_atomic(path, buf.getvalue())
        except OSError as exc:  # a cache that cannot be written costs the next run the rendering, nothing else
            log.warning("%s: replay frames not cached (%s)", path, exc)
    return TrainingSet(rgb, labels, depth, label_set, [scene.name for scene in scenes for _ in picks])


@dataclass
class Replay:
    """The images replayed during adaptation and the validation images that measure forgetting (None: none),
    with where they came from."""

    train: TrainingSet | None
    val: TrainingSet | None
    source: str
    plan: ReplayPlan | None = None

    def describe(self) -> dict:
        return {"source": self.source, "images": 0 if self.train is None else len(self.train),
                "val_images": 0 if self.val is None else len(self.val),
                **({} if self.plan is None else {"plan": self.plan.to_dict()})}


def plan_replay(plan: ReplayPlan, size: tuple[int, int], label_set: LabelSet, *, scenes: int = REPLAY_SCENES,
                frames: int = REPLAY_FRAMES, val_frames: int = VAL_FRAMES_PER_SCENE,
                cache: Path | None = None) -> Replay:
    """``frames`` frames of ``scenes`` scenes of ``plan`` and ``val_frames`` of each validation scene, rendered."""
    chosen = balanced(plan.scenes, scenes)
    train = render_scenes(chosen, plan.frames, evenly(plan.frames, frames), size, label_set,
                          path_seconds=plan.path_seconds, cache=cache)
    val = None
    if plan.val_scenes:
        val = render_scenes(plan.val_scenes, plan.val_frames, evenly(plan.val_frames, val_frames), size, label_set,
                            path_seconds=plan.path_seconds, cache=cache)
    kept = ReplayPlan(tuple(chosen), plan.frames, plan.path_seconds, plan.val_scenes, plan.val_frames, plan.source)
    return Replay(train, val, f"simulated scenes of {plan.source}", kept)


def folder_replay(folders: Sequence[Path], size: tuple[int, int], label_set: LabelSet, *, need_depth: bool,
                  images: int = REPLAY_FOLDER_IMAGES) -> Replay:
    """``images`` images spread over the training folders ``folders`` (read as ``semmap train --data``)."""
    data = gather(list(folders), size, label_set=label_set, need_depth=need_depth)
    pick = np.asarray(evenly(len(data), images), np.int64)
    train = TrainingSet(data.rgb[pick], data.labels[pick], None if data.depth is None else data.depth[pick],
                        label_set, [data.sources[i] for i in pick])
    return Replay(train, None, ", ".join(map(str, folders)))


def find_replay(meta: dict, weights: Path, size: tuple[int, int], label_set: LabelSet, *, need_depth: bool,
                folders: Sequence[Path] = (), shipped_manifest: Path | None = None, scenes: int = REPLAY_SCENES,
                frames: int = REPLAY_FRAMES, cache: Path | None = None) -> Replay:
    """The replay of the network in ``weights`` (metadata ``meta``), first found of: ``folders``, the weight
    file's own plan, the shipped manifest's scenes (``shipped_manifest``, when the weights or the network they
    were adapted from are listed there), the folders of its ``semmap train`` run; an empty replay otherwise."""
    if folders:
        return folder_replay(folders, size, label_set, need_depth=need_depth)
    if isinstance(meta.get("replay"), dict):
        plan = ReplayPlan.from_dict(meta["replay"], f"{weights} (meta.replay)")
        return plan_replay(plan, size, label_set, scenes=scenes, frames=frames, cache=cache)
    if shipped_manifest is not None and shipped_manifest.is_file():
        try:
            manifest = json.loads(shipped_manifest.read_text())
        except (OSError, ValueError) as exc:
            raise FormatError(f"{shipped_manifest}: unreadable weights manifest ({type(exc).__name__})") from None
        if _listed(manifest, shipped_manifest.parent, weights, meta):
            plan = manifest_plan(manifest, str(shipped_manifest))
            return plan_replay(plan, size, label_set, scenes=scenes, frames=frames, cache=cache)
    data = [Path(p) for p in (meta.get("settings") or {}).get("data", ())]
    if data and all(p.is_dir() for p in data):
        return folder_replay(data, size, label_set, need_depth=need_depth)
    return Replay(None, None, "none")


def _listed(manifest: dict, root: Path, weights: Path, meta: dict) -> bool:
    """Whether ``weights`` (or the network they were adapted from, ``meta.adapted_from.sha256``) is a network of
    ``manifest``."""
    origin = (meta.get("adapted_from") or {}).get("sha256")
    for entry in (manifest.get("networks") or {}).values():
        if not isinstance(entry, dict):
            continue
        if (root / str(entry.get("file", ""))).resolve() == Path(weights).resolve():
            return True
        if origin is not None and entry.get("sha256") == origin:
            return True
    return False
