"""Map kinds by name, as ``semmap run --maps`` selects them: each kind's class, the files it writes, the fusion
rules it takes and its kernels. Plain data, no run configuration: :mod:`semmap.factories` builds maps from one."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import TYPE_CHECKING

from semmap.errors import ConfigError
from semmap.fusion.rules import FusionRule
from semmap.registry import Registry

if TYPE_CHECKING:
    from semmap.maps.base import SemanticMap


@dataclass(frozen=True)
class MapEntry:
    """A map kind: the class (``factory()``, imported on first use), one line of help, the stem of its files, its
    own fusion rule and the rules it can fuse with, and the kernels to compile before the first frame."""

    name: str
    factory: Callable[[], type[SemanticMap]]
    help: str
    stem: str  #: its files are ``<stem>.ot`` / ``.bt`` / ``.semmap`` / ``.ply``
    default_fusion: FusionRule  #: its paper's rule, used when ``--fusion`` is not given
    fusion_rules: tuple[FusionRule, ...]  #: the rules it can fuse with
    compile_kernels: Callable[[], None]
    extra_files: tuple[str, ...] = ()  #: files it writes beside ``<stem>.*`` (the TSDF's ``mesh.ply``)

    def files(self) -> set[str]:
        """Names of the files its ``save`` may write in a run folder, and its preview."""
        return {f"{self.stem}.ot", f"{self.stem}.bt", f"{self.stem}.semmap", f"{self.stem}.ply",
                f"preview_{self.name}.png", *self.extra_files}


def _octomap() -> type[SemanticMap]:
    from semmap.maps.semantic_octomap import SemanticOctoMap

    return SemanticOctoMap


def _voxel_grid() -> type[SemanticMap]:
    from semmap.maps.voxel_grid import SemanticVoxelGrid

    return SemanticVoxelGrid


def _point_map() -> type[SemanticMap]:
    from semmap.maps.point_map import SemanticPointMap

    return SemanticPointMap


def _tsdf() -> type[SemanticMap]:
    from semmap.maps.tsdf import TsdfMap

    return TsdfMap


def _octomap_kernels() -> None:
    from semmap.maps.semantic_octomap import compile_kernels

    compile_kernels()


def _grid_kernels() -> None:
    from semmap.maps.semantic_grid import compile_kernels

    compile_kernels()


def _tsdf_kernels() -> None:
    from semmap.maps.semantic_grid import compile_kernels as grid_kernels
    from semmap.maps.tsdf import compile_kernels

    grid_kernels()
    compile_kernels()


#: Every map kind, in the order a run folder is searched for a map (the first is ``--maps``'s default).
MAPS: Registry[MapEntry] = Registry("map", [
    MapEntry("octomap", _octomap, "semantic OctoMap: occupancy + free space + fused classes (maps.semantic_octomap)",
             stem="map", default_fusion=FusionRule.TOPK, fusion_rules=tuple(FusionRule),
             compile_kernels=_octomap_kernels),
    MapEntry("voxelgrid", _voxel_grid, "dense-K semantic voxel grid (maps.voxel_grid)", stem="voxelgrid",
             default_fusion=FusionRule.BAYES, fusion_rules=tuple(FusionRule), compile_kernels=_grid_kernels),
    MapEntry("points", _point_map, "fine voxel-filtered semantic point map (maps.point_map)", stem="points",
             default_fusion=FusionRule.BAYES_PRIOR, fusion_rules=tuple(FusionRule), compile_kernels=_grid_kernels),
    MapEntry("tsdf", _tsdf, "truncated signed distance field with a voxel grid's classes; writes the semantic mesh "
             "mesh.ply (maps.tsdf)", stem="tsdf", default_fusion=FusionRule.BAYES, fusion_rules=tuple(FusionRule),
             compile_kernels=_tsdf_kernels, extra_files=("mesh.ply",)),
], option="--maps")
#: The maps ``semmap run --maps`` builds, as an enum (see :mod:`semmap.maps.base`).
MapKind = MAPS.enum("MapKind", __name__, str_mixin=True)
#: Each map's own rule (its paper's) when ``--fusion`` is not given.
DEFAULT_FUSION = {MapKind(n): e.default_fusion for n, e in MAPS.items()}
#: Rules each map can fuse with (the OctoMap's voxels keep top-k sets).
SUPPORTED_FUSION = {MapKind(n): e.fusion_rules for n, e in MAPS.items()}


def own_rules() -> str:
    """``"octomap topk, voxelgrid bayes, ..."``: each map's own fusion rule, for help texts."""
    return ", ".join(f"{name} {entry.default_fusion.value}" for name, entry in MAPS.items())


def map_kind(value: str | MapKind) -> MapKind:
    """``"octomap"`` -> :attr:`MapKind.OCTOMAP`, or a ConfigError listing the kinds."""
    if value not in MAPS:
        raise ConfigError(MAPS.unknown(value))
    return MapKind(value)


def compile_kernels(kinds: Iterable[MapKind]) -> float:
    """Compile (or load from numba's cache) the kernels of the given map kinds now, so that first-use
    compilation stays out of the per-frame timings; returns the seconds it took."""
    t = time.perf_counter()
    for compile_family in dict.fromkeys(MAPS[kind].compile_kernels for kind in kinds):
        compile_family()
    return time.perf_counter() - t
