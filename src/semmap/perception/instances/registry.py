"""Instance sources by name, as ``semmap run --instances NAME`` selects them."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from semmap.errors import ConfigError
from semmap.perception.base import Segmenter
from semmap.perception.instances.base import InstanceSource
from semmap.registry import Registry
from semmap.types import LabelSet


@dataclass(frozen=True)
class InstanceSourceEntry:
    """An instance source by name: its factory (the keywords of :func:`make_instance_source`), one line of help,
    and what it needs."""

    name: str
    factory: Callable[..., InstanceSource]
    help: str
    needs_weights: bool = False  #: ``--instance-weights`` is required
    needs_classes: bool = False  #: needs class probabilities (a segmenter or labelled frames)
    simulated: bool = False  #: reads the simulator's instance images (simulated sequences only)


def _oracle(*, label_set: LabelSet | None, preset: str, seed: int, **_) -> InstanceSource:
    from semmap.perception.instances.oracle import OracleInstances

    if label_set is None:
        from semmap.labels import INDOOR_LABELS

        label_set = INDOOR_LABELS
    return OracleInstances(label_set, preset=preset, seed=seed)


def _components(*, label_set: LabelSet | None, segmenter: Segmenter | None, **_) -> InstanceSource:
    from semmap.perception.instances.components import ComponentInstances

    if segmenter is None and label_set is None:
        raise ConfigError("--instances components needs class probabilities: a segmenter (--segmenter, "
                          "--semantics oracle) or labelled frames")
    return ComponentInstances(segmenter.label_set if segmenter is not None else label_set, segmenter)


def _maskrcnn(*, weights: Path | None, **_) -> InstanceSource:
    from semmap.perception.instances.maskrcnn import MaskRcnnInstances

    if weights is None:
        raise ConfigError("--instances maskrcnn needs weights: --instance-weights maskrcnn_resnet50_fpn.pth "
                          "(none can be downloaded here)")
    return MaskRcnnInstances.from_weights(weights)


#: Every instance source ``--instances`` can name.
INSTANCE_SOURCES: Registry[InstanceSourceEntry] = Registry("instance source", [
    InstanceSourceEntry("oracle", _oracle, "the simulator's instance images with a detector-like error model "
                        "(--instance-errors PRESET)", simulated=True),
    InstanceSourceEntry("components", _components, "connected regions of each object class of the run's "
                        "segmenter, cut at depth jumps", needs_classes=True),
    InstanceSourceEntry("maskrcnn", _maskrcnn, "torchvision's Mask R-CNN with your weights (--instance-weights "
                        "maskrcnn_resnet50_fpn.pth)", needs_weights=True),
])
#: The instance source names as an enum (the type of ``objects.instances`` in the run configuration).
InstanceSourceName = INSTANCE_SOURCES.enum("InstanceSourceName", __name__)


def make_instance_source(name: str, *, label_set: LabelSet | None = None, segmenter: Segmenter | None = None,
                         weights: Path | None = None, preset: str = "maskrcnn-like", seed: int = 0) -> InstanceSource:
    """Build the instance source ``name``; ``label_set`` is the dataset's (the oracle reports its classes),
    ``segmenter`` the run's (``components`` splits its classes into instances, or the dataset's labels')."""
    return INSTANCE_SOURCES[name].factory(label_set=label_set, segmenter=segmenter, weights=weights, preset=preset,
                                          seed=seed)
