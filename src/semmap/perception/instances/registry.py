"""Instance sources by name, as ``semmap run --instances NAME`` selects them."""

from __future__ import annotations

from pathlib import Path

from semmap.errors import ConfigError
from semmap.perception.base import Segmenter
from semmap.perception.instances.base import InstanceSource
from semmap.types import LabelSet

#: name -> what it needs, for help texts and errors.
INSTANCE_SOURCES = {
    "oracle": "the simulator's instance images with a detector-like error model (--instance-errors PRESET)",
    "components": "connected regions of each object class of the run's segmenter, cut at depth jumps",
    "maskrcnn": "torchvision's Mask R-CNN with your weights (--instance-weights maskrcnn_resnet50_fpn.pth)",
}


def make_instance_source(name: str, *, label_set: LabelSet | None = None, segmenter: Segmenter | None = None,
                         weights: Path | None = None, preset: str = "maskrcnn-like", seed: int = 0) -> InstanceSource:
    """Build the instance source ``name``; ``label_set`` is the dataset's (the oracle reports its classes),
    ``segmenter`` the run's (``components`` splits its classes into instances, or the dataset's labels')."""
    if name == "oracle":
        from semmap.perception.instances.oracle import OracleInstances

        if label_set is None:
            from semmap.labels import INDOOR_LABELS

            label_set = INDOOR_LABELS
        return OracleInstances(label_set, preset=preset, seed=seed)
    if name == "components":
        from semmap.perception.instances.components import ComponentInstances

        if segmenter is None and label_set is None:
            raise ConfigError("--instances components needs class probabilities: a segmenter (--segmenter, "
                              "--semantics oracle) or labelled frames")
        return ComponentInstances(segmenter.label_set if segmenter is not None else label_set, segmenter)
    if name == "maskrcnn":
        from semmap.perception.instances.maskrcnn import MaskRcnnInstances

        if weights is None:
            raise ConfigError("--instances maskrcnn needs weights: --instance-weights maskrcnn_resnet50_fpn.pth "
                              "(none can be downloaded here)")
        return MaskRcnnInstances.from_weights(weights)
    raise ConfigError(f"unknown instance source {name!r}; choose one of {', '.join(INSTANCE_SOURCES)}")
