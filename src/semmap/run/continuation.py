"""``semmap run SEQ --continue PRIOR``: a run that goes on from a finished run's maps instead of empty ones.

:func:`open_prior` reads the prior (a run folder or one ``.semmap`` map file) and refuses, in one line and before
any work, a prior the run cannot continue: another resolution, map kind, fusion rule or setting, occupancy model
or state type (the label set is checked once the run knows its classes, before the first frame).
:meth:`PriorRun.restored` gives the run's maps the prior's state (its evidence keeps accumulating), and
:meth:`PriorRun.align` localizes the recording's first frames in the prior (Monte-Carlo localization, then ICP;
:mod:`semmap.localization.align`) so that every pose is carried into the prior's frame.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from semmap.config import LoopMode, MappingConfig, RunConfig
from semmap.errors import ConfigError, FormatError
from semmap.files.outputs import OutputKind, check_outputs
from semmap.files.safe import path_kind
from semmap.fusion.rules import FusionRule
from semmap.io.map_files import load_map, native_file
from semmap.maps.base import SemanticMap
from semmap.maps.registry import MapKind
from semmap.poses.frame_poses import FramePoses
from semmap.types import LabelSet

log = logging.getLogger("semmap")
OPTION = "--continue"


@dataclass
class PriorRun:
    """The prior's maps by kind (loaded from ``files``), as the run continues them."""

    path: Path
    files: dict[MapKind, Path]
    maps: dict[MapKind, SemanticMap]
    surface: np.ndarray | None = None  # the finest surface points the prior holds (a point map's), for ICP

    def restored(self, maps: list[SemanticMap], label_set: LabelSet | None) -> list[SemanticMap]:
        """The run's freshly built ``maps`` holding the prior's state; a prior of another label set is refused."""
        for m in maps:
            prior = self.maps[m.kind]
            _same(self.files[m.kind], "label set", _labels(prior.label_set), _labels(label_set),
                  "map with the same segmenter or --semantics as the prior run")
            m.restore(prior.state())
        return maps

    def align(self, dataset, pose_of: FramePoses, segment, mapping: MappingConfig) -> dict:
        """Localize the recording's first frames (their class sets from ``segment``, depth within ``mapping``'s
        range) in the prior and set ``pose_of.transform``; the report's ``continued`` section."""
        from semmap.localization.align import align_recording
        from semmap.localization.prior import prior_from_grid_map, prior_from_octomap

        t0 = time.perf_counter()
        primary = next(iter(self.maps.values()))
        prior = prior_from_octomap(primary) if primary.kind == MapKind.OCTOMAP else prior_from_grid_map(primary)

        def frames():
            for frame in dataset:
                T, _ = pose_of.source_pose(frame)
                if T is not None:
                    yield frame, T

        try:
            a = align_recording(prior, frames(), segment=segment, surface=self.surface, min_depth=mapping.min_depth,
                                max_depth=mapping.max_depth)
        except ConfigError as exc:
            raise ConfigError(f"{OPTION} {self.path}: {exc}") from None
        pose_of.transform = a.T_prior_seq
        report = {"prior": str(self.path), "maps": {k.value: str(p) for k, p in self.files.items()},
                  "icp_surface": "point map" if self.surface is not None else "occupied voxel centres",
                  **a.report(), "seconds": round(time.perf_counter() - t0, 2)}
        log.info("%s: the recording is localized in the prior after %d frames (ICP residual %s m)", OPTION,
                 a.converged_after, a.icp.get("rms_residual_m"))
        return report


def _labels(label_set: LabelSet | None) -> str:
    if label_set is None:
        return "none"
    return f"{len(label_set)} classes ({', '.join(label_set.names[:3])}...)"


def _same(path: Path, what: str, prior, run, hint: str) -> None:
    """One line naming the file and the mismatch, unless the prior's ``what`` equals the run's."""
    if prior != run:
        raise ConfigError(f"{OPTION} {path}: the prior map's {what} is {prior}, this run's {run}; it cannot be "
                          f"continued ({hint})")


def _settings(m: SemanticMap) -> dict[str, tuple[object, str]]:
    """What a map's evidence means, by name: (value, how to match it)."""
    f = m.fusion
    fusion = f.to_dict()
    keys = ("k", "lam", "max_confidence") if f.rule == FusionRule.TOPK else tuple(k for k in fusion if k != "prior")
    out: dict[str, tuple[object, str]] = {
        "resolution": (m.resolution, "pass --resolution (or --point-resolution) as the prior run did"),
        "fusion rule": (f.rule.value, "pass --fusion as the prior run did"),
        "fusion settings": ({k: fusion[k] for k in keys if k != "rule"},
                            "pass --top-k, --lambda and --max-confidence as the prior run did")}
    occupancy = getattr(m, "occupancy", None)
    if occupancy is not None:
        out["occupancy model"] = ({k: round(float(v), 6) for k, v in vars(occupancy).items()},
                                  "the prior run's --prob-hit / --prob-miss / clamps")
    grid = getattr(m, "grid", None)
    if grid is not None:
        out["state type"] = (grid.dtype, "pass --state-dtype as the prior run did")
    for name in ("free_space", "truncation", "max_range"):
        if hasattr(m, name):
            out[name.replace("_", " ")] = (getattr(m, name), f"the prior run's --{name.replace('_', '-')}")
    return out


def _map_files(path: Path, kinds: tuple[MapKind, ...]) -> dict[MapKind, Path]:
    """The prior's file of each map kind the run builds: a run folder's, or the one map file given."""
    if path.is_dir():
        files = {kind: path / native_file(kind) for kind in kinds}
        missing = [f"{p.name} ({k.value})" for k, p in files.items() if not p.is_file()]
        if missing:
            raise ConfigError(f"{OPTION} {path}: the folder has no {', '.join(missing)}; this run builds "
                              f"{', '.join(k.value for k in kinds)} (pass --maps with the kinds the prior holds)")
        return files
    if not path.is_file():
        raise ConfigError(f"{OPTION} {path} {path_kind(path)} (give a finished run's folder or its .semmap map file)")
    if path.suffix != ".semmap":
        raise ConfigError(f"{OPTION} {path}: not a semmap map file (give a run folder or its map.semmap, "
                          "voxelgrid.semmap, points.semmap or tsdf.semmap)")
    if len(kinds) != 1:
        raise ConfigError(f"{OPTION} {path}: one map file, but this run builds {', '.join(k.value for k in kinds)} "
                          "(give the prior's run folder, or --maps with its one kind)")
    return {kinds[0]: path}


def open_prior(path: Path, config: RunConfig, *, checkpoint_every: int = 0, resume: bool = False) -> PriorRun:
    """Read the prior ``path`` (a run folder or a map file) for a run of ``config``; refuses, in one line naming
    the file and the mismatch, a prior the run cannot continue and the options a continued run does not take."""
    from semmap.factories import get_map
    from semmap.poses.track import METHODS, OBJECT_METHODS

    path = Path(path)
    if checkpoint_every or resume:
        raise ConfigError(f"{OPTION} does not take --checkpoint-every / --resume (the alignment is not "
                          "checkpointed); run it again from the start")
    if config.mode == LoopMode.ONLINE and config.poses.source in (*METHODS, *OBJECT_METHODS):
        raise ConfigError(f"{OPTION} needs the recording's poses before mapping: track offline (drop --online) or "
                          "pass ground truth or a trajectory file as --poses")
    check_outputs([("--out", config.output.out, OutputKind.FOLDER)], [(OPTION, path)])
    files = _map_files(path, tuple(config.mapping.maps))
    maps: dict[MapKind, SemanticMap] = {}
    for kind, file in files.items():
        try:
            m = load_map(file)
        except FormatError as exc:
            raise ConfigError(f"{OPTION} {exc}") from None
        _same(file, "map kind", m.kind.value, kind.value, "--maps names the kinds to continue")
        fresh = get_map(kind, config, m.label_set)
        ours = _settings(fresh)
        for what, (value, hint) in _settings(m).items():
            _same(file, what, value, ours[what][0], hint)
        maps[kind] = m
    points = path / native_file(MapKind.POINTS) if path.is_dir() else None
    surface = None
    if MapKind.POINTS in maps:
        surface = maps[MapKind.POINTS].cloud().centers
    elif points is not None and points.is_file():
        surface = load_map(points).cloud().centers  # (not continued, only its surface for the alignment)
    return PriorRun(path, files, maps, surface)
