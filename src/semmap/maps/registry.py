"""Maps by kind, as ``semmap run --maps`` selects them: the only place that reads the run configuration for maps."""

from __future__ import annotations

import time
from collections.abc import Iterable

from semmap.config import RunConfig
from semmap.errors import ConfigError
from semmap.maps.base import SemanticMap
from semmap.types import LabelSet, MapKind


def map_kind(value: str | MapKind) -> MapKind:
    """``"octomap"`` -> :attr:`MapKind.OCTOMAP`, or a ConfigError listing the kinds."""
    try:
        return MapKind(value)
    except ValueError:
        raise ConfigError(f"unknown map {value!r}; choose from {', '.join(k.value for k in MapKind)}") from None


def get_map(kind: MapKind, config: RunConfig, label_set: LabelSet | None) -> SemanticMap:
    """An empty map of ``kind`` with the run's resolution, sensor model, fusion settings and label set."""
    m, s = config.mapping, config.semantics
    if kind == MapKind.OCTOMAP:
        from semmap.maps.semantic_octomap import OccupancyParams, SemanticOctoMap, SemanticParams

        return SemanticOctoMap(m.resolution, label_set=label_set, max_range=m.max_range,
                               occupancy=OccupancyParams(m.prob_hit, m.prob_miss, m.clamp_min, m.clamp_max),
                               semantics=SemanticParams(s.k, s.lam, s.max_confidence),
                               color_mode=config.output.color_mode.value)
    raise ConfigError(f"map {kind.value!r} is not available yet")


def compile_kernels(kinds: Iterable[MapKind]) -> float:
    """Compile (or load from numba's cache) the kernels of the given map kinds now, so that first-use
    compilation stays out of the per-frame timings; returns the seconds it took."""
    t = time.perf_counter()
    for kind in dict.fromkeys(kinds):
        if kind == MapKind.OCTOMAP:
            from semmap.maps.semantic_octomap import compile_kernels as octomap_kernels

            octomap_kernels()
    return time.perf_counter() - t
