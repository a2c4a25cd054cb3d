"""The classes a real recording gets without ``--segmenter``: ``espnetv2+structure`` (a network trained on real
photographs for the objects, wall / floor / ceiling from depth and gravity), said in one line; and one warning
line when a network semmap trained on simulated rooms only is run on a real recording."""

from __future__ import annotations

import logging

from semmap.config import RunConfig, SemanticSource
from semmap.datasets import Dataset
from semmap.perception.registry import ESPNETV2, TRAINED_NETWORKS, SegmenterName, shipped_espnetv2

log = logging.getLogger("semmap")

#: What ``semmap run`` segments a real recording with when nothing is named.
REAL_DEFAULT = f"{ESPNETV2}+structure"


def is_simulated(config: RunConfig, dataset: Dataset | None) -> bool:
    """Whether the frames come from semmap's simulator (an in-memory scene or a ``semmap simulate`` folder)."""
    from semmap.run.prepare import simulated_realism

    return simulated_realism(dataset, config.input.dataset) is not None


def _has_labels(config: RunConfig, dataset: Dataset | None) -> bool:
    """Whether the recording brings its own classes (a label folder, a label set, labels or class probabilities
    on its first frame)."""
    from semmap.factories import open_dataset_of

    if config.input.labels is not None:
        return True
    ds = dataset if dataset is not None else open_dataset_of(config.input, max_frames=1)
    if ds.label_set is not None:
        return True
    first = next(iter(ds), None)
    return first is not None and (first.labels is not None or first.semantics is not None)


def with_real_default(config: RunConfig, dataset: Dataset | None = None) -> RunConfig:
    """``config`` with ``semantics.segmenter = espnetv2`` and ``structure`` on when it names no segmenter, asks
    for nothing else (``--semantics auto``) and the recording is real and unlabelled; the same config otherwise.
    Warns once when a network trained on simulated rooms only meets a real recording."""
    s = config.semantics
    if s.segmenter is not None:
        if s.segmenter in TRAINED_NETWORKS and s.weights is None and not is_simulated(config, dataset):
            log.warning("%s was trained on semmap's simulated rooms only and labels real rooms poorly; for real "
                        "recordings use the default %s (run without --segmenter)",
                        SegmenterName(s.segmenter).value + ("+structure" if s.add_structure else ""), REAL_DEFAULT)
        return config
    if s.source != SemanticSource.AUTO or is_simulated(config, dataset) or _has_labels(config, dataset):
        return config
    if not shipped_espnetv2().is_file():
        log.warning("no --segmenter and no shipped ESPNetv2 weights (%s): mapping geometry and colour only",
                    shipped_espnetv2())
        return config
    log.info("no --segmenter and no label images: segmenting with the real-world default %s (ESPNetv2-PASCAL's "
             "objects, wall / floor / ceiling from depth and gravity); --semantics none maps geometry only",
             REAL_DEFAULT)
    semantics = s.model_copy(update={"segmenter": SegmenterName(ESPNETV2), "add_structure": True})
    return config.model_copy(update={"semantics": semantics})
