"""Maps by kind, as ``semmap run --maps`` selects them: the only place that reads the run configuration for maps."""

from __future__ import annotations

import json
import time
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from semmap.config import RunConfig
from semmap.errors import ConfigError
from semmap.fusion.rules import FusionParams, FusionRule, fusion_rule
from semmap.maps.base import SemanticMap
from semmap.types import LabelSet, MapKind

#: Each map's own rule (its paper's) when ``--fusion`` is not given.
DEFAULT_FUSION = {MapKind.OCTOMAP: FusionRule.TOPK, MapKind.VOXELGRID: FusionRule.BAYES,
                  MapKind.POINTS: FusionRule.BAYES_PRIOR}
#: Rules each map can fuse with.
SUPPORTED_FUSION = {MapKind.OCTOMAP: tuple(FusionRule), MapKind.VOXELGRID: tuple(FusionRule),
                    MapKind.POINTS: tuple(FusionRule)}


def map_kind(value: str | MapKind) -> MapKind:
    """``"octomap"`` -> :attr:`MapKind.OCTOMAP`, or a ConfigError listing the kinds."""
    try:
        return MapKind(value)
    except ValueError:
        raise ConfigError(f"unknown map {value!r}; choose from {', '.join(k.value for k in MapKind)}") from None


def get_fusion(kind: MapKind, config: RunConfig, label_set: LabelSet | None) -> FusionParams:
    """The fusion rule and settings ``kind`` uses in this run (``--fusion``, else the map's own rule)."""
    s = config.semantics
    rule = DEFAULT_FUSION[kind] if s.fusion is None else fusion_rule(s.fusion)
    if rule not in SUPPORTED_FUSION[kind]:
        raise ConfigError(f"the {kind.value} map fuses with {', '.join(r.value for r in SUPPORTED_FUSION[kind])} "
                          f"only; build a voxelgrid or points map for {rule.value!r} (--maps)")
    prior = None
    if rule == FusionRule.BAYES_PRIOR and s.class_prior is not None and label_set is not None:
        prior = read_class_prior(s.class_prior, label_set)
    return FusionParams(rule, k=s.k, lam=s.lam, max_confidence=s.max_confidence, prior=prior)


def read_class_prior(path: Path, label_set: LabelSet) -> np.ndarray:
    """Class frequencies (K,) from a JSON object ``{class name: frequency}`` (classes not named get 0)."""
    try:
        d = json.loads(Path(path).read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise ConfigError(f"{path}: cannot read the class prior ({exc})") from None
    if not isinstance(d, dict) or not all(isinstance(v, int | float) for v in d.values()):
        raise ConfigError(f"{path}: the class prior must be a JSON object of class name -> frequency")
    unknown = set(d) - set(label_set.names)
    if unknown:
        raise ConfigError(f"{path}: classes not in the label set: {', '.join(sorted(unknown))}")
    return np.array([float(d.get(name, 0.0)) for name in label_set.names])


def get_map(kind: MapKind, config: RunConfig, label_set: LabelSet | None) -> SemanticMap:
    """An empty map of ``kind`` with the run's resolution, sensor model, fusion settings and label set."""
    m = config.mapping
    fusion = get_fusion(kind, config, label_set)
    from semmap.maps.semantic_octomap import OccupancyParams

    occupancy = OccupancyParams(m.prob_hit, m.prob_miss, m.clamp_min, m.clamp_max)
    if kind == MapKind.OCTOMAP:
        from semmap.maps.semantic_octomap import SemanticOctoMap

        return SemanticOctoMap(m.resolution, label_set=label_set, max_range=m.max_range, occupancy=occupancy,
                               fusion=fusion, color_mode=config.output.color_mode.value)
    if kind == MapKind.VOXELGRID:
        from semmap.maps.voxel_grid import SemanticVoxelGrid

        return SemanticVoxelGrid(m.resolution, label_set=label_set, fusion=fusion, dtype=m.state_dtype or "float32",
                                 free_space=m.free_space, occupancy=occupancy, max_range=m.max_range)
    if kind == MapKind.POINTS:
        from semmap.maps.point_map import SemanticPointMap

        return SemanticPointMap(m.point_resolution, label_set=label_set, fusion=fusion,
                                dtype=m.state_dtype or "float16")
    raise ConfigError(f"unknown map kind {kind!r}")


def compile_kernels(kinds: Iterable[MapKind]) -> float:
    """Compile (or load from numba's cache) the kernels of the given map kinds now, so that first-use
    compilation stays out of the per-frame timings; returns the seconds it took."""
    from semmap.maps.semantic_grid import compile_kernels as grid_kernels
    from semmap.maps.semantic_octomap import compile_kernels as octomap_kernels

    warm_up = {MapKind.OCTOMAP: octomap_kernels, MapKind.VOXELGRID: grid_kernels, MapKind.POINTS: grid_kernels}
    t = time.perf_counter()
    for compile_family in dict.fromkeys(warm_up[kind] for kind in kinds):
        compile_family()
    return time.perf_counter() - t
