"""Components built from a run configuration: the maps, their fusion settings, the segmenter and the instance
source a ``RunConfig`` names. The run layer's only readers of the configuration for them; the components and
their registries (``maps/registry.py``, ``perception/registry.py``, ...) take plain arguments."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from semmap.config import InputConfig, LoopMode, RunConfig, SemanticSource
from semmap.datasets import Dataset
from semmap.errors import ConfigError
from semmap.files.safe import read_text_limited
from semmap.fusion.rules import FusionParams, FusionRule, fusion_rule
from semmap.maps.base import SemanticMap
from semmap.maps.registry import DEFAULT_FUSION, MAPS, SUPPORTED_FUSION, MapKind
from semmap.types import LabelSet


def get_fusion(kind: MapKind, config: RunConfig, label_set: LabelSet | None) -> FusionParams:
    """The fusion rule and settings ``kind`` uses in this run (``--fusion``, else the map's own rule)."""
    s = config.semantics
    rule = DEFAULT_FUSION[kind] if s.fusion is None else fusion_rule(s.fusion)
    if rule not in SUPPORTED_FUSION[kind]:
        able = " or ".join(name for name, entry in MAPS.items() if rule in entry.fusion_rules)
        raise ConfigError(f"the {kind.value} map fuses with {', '.join(r.value for r in SUPPORTED_FUSION[kind])} "
                          f"only; build a {able} map for {rule.value!r} (--maps)")
    prior = None
    if rule == FusionRule.BAYES_PRIOR and s.class_prior is not None and label_set is not None:
        prior = read_class_prior(s.class_prior, label_set)
    return FusionParams(rule, k=s.k, lam=s.lam, max_confidence=s.max_confidence, prior=prior)


def read_class_prior(path: Path, label_set: LabelSet) -> np.ndarray:
    """Class frequencies (K,) from a JSON object ``{class name: frequency}`` (classes not named get 0)."""
    text = read_text_limited(path, what="class prior", error=lambda reason: ConfigError(f"{path}: {reason}"))
    try:
        d = json.loads(text)
    except json.JSONDecodeError as exc:
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
                               fusion=fusion, color_mode=config.output.color_mode.value,
                               cell_evidence=m.cell_evidence, decay=m.decay)
    if kind == MapKind.VOXELGRID:
        from semmap.maps.voxel_grid import SemanticVoxelGrid

        return SemanticVoxelGrid(m.resolution, label_set=label_set, fusion=fusion, dtype=m.state_dtype or "float32",
                                 free_space=m.free_space, occupancy=occupancy, max_range=m.max_range,
                                 decay=m.decay)
    if kind == MapKind.POINTS:
        from semmap.maps.point_map import SemanticPointMap

        return SemanticPointMap(m.point_resolution, label_set=label_set, fusion=fusion,
                                dtype=m.state_dtype or "float16")
    if kind == MapKind.TSDF:
        from semmap.maps.tsdf import TsdfMap

        return TsdfMap(m.tsdf_voxel or m.resolution, label_set=label_set, fusion=fusion,
                       dtype=m.state_dtype or "float32", truncation=m.tsdf_truncation)
    raise ConfigError(f"unknown map kind {kind!r}")


def segmenter_for(config: RunConfig, dataset: Dataset | None = None):
    """The segmenter the configuration names (``--segmenter``, or ``--semantics oracle``), or None; ``dataset``
    (when already open) gives a segmenter that predicts the dataset's classes its label set."""
    from semmap.perception.registry import SEGMENTERS, SegmenterName, make_segmenter
    from semmap.perception.structure.gravity import parse_up

    s = config.semantics
    name = s.segmenter or (SegmenterName.ORACLE if s.source == SemanticSource.ORACLE else None)
    if name is None:
        return None
    label_set = None
    if SEGMENTERS[name].dataset_classes:
        label_set = (dataset if dataset is not None else open_dataset_of(config.input, max_frames=1)).label_set
    # online, the network has one core to itself beside tracking and mapping (its own threads would fight theirs)
    threads = config.online.segment_threads if config.mode == LoopMode.ONLINE else None
    return make_segmenter(name, weights=s.weights, label_set=label_set, k=s.k, label_confidence=s.label_confidence,
                          oracle_preset=s.oracle_preset, seed=s.seed, backend=s.backend, batch_size=s.batch_size,
                          input_size=s.input_size, threads=threads, trust_weights=s.trust_weights, model=s.model,
                          model_config=s.segmenter_config, class_map=s.class_map, calibration=s.calibration,
                          structure=s.add_structure, up_world=None if s.up is None else parse_up(s.up))


def instance_source_for(config: RunConfig, segmenter, dataset: Dataset | None = None):
    """The instance source ``--instances`` names (None without it)."""
    o = config.objects
    if o.instances is None:
        return None
    from semmap.perception.instances import make_instance_source

    label_set = None
    if segmenter is None:
        label_set = (dataset if dataset is not None else open_dataset_of(config.input, max_frames=1)).label_set
    return make_instance_source(o.instances, label_set=label_set, segmenter=segmenter, weights=o.weights,
                                preset=o.errors, seed=o.seed)


def open_dataset_of(c: InputConfig, *, max_frames: int | None = None) -> Dataset:
    """The dataset a run's input section names (``max_frames`` overrides its own, e.g. 1 to read a label set)."""
    from semmap.datasets import open_dataset

    return open_dataset(c.dataset, c.format, labels=c.labels, stride=c.stride,
                        max_frames=c.max_frames if max_frames is None else max_frames, raw_color=c.raw_color,
                        ros=c.ros.options(), strict=c.strict)
