"""The instance-source interface: a frame in, object instances (masks, classes, scores, features) out."""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

from semmap.types import Frame, Instances, LabelSet, TopKProbs

#: Class names that are never objects: the room shell and "no class" (any label set; compared in lower case).
STUFF_NAMES = frozenset({"unknown", "background", "void", "wall", "floor", "ceiling"})


@runtime_checkable
class InstanceSource(Protocol):
    """Anything that finds object instances in a frame, with classes from its ``label_set``."""

    #: Short name used in reports (``oracle``, ``components``, ``maskrcnn``).
    name: str
    #: True when :meth:`detect` builds on the run's class probabilities (frames without them are skipped).
    needs_semantics: bool

    @property
    def label_set(self) -> LabelSet: ...

    def detect(self, frame: Frame, semantics: TopKProbs | None = None) -> Instances:
        """Instances in ``frame``; ``semantics`` are the frame's class probabilities when the run already has them
        (sources built on a segmentation use them instead of segmenting again)."""
        ...


def thing_classes(label_set: LabelSet) -> np.ndarray:
    """(K,) bool: which classes of ``label_set`` are objects (everything but :data:`STUFF_NAMES` and id 0)."""
    things = np.array([name.lower() not in STUFF_NAMES for name in label_set.names], bool)
    things[0] = False
    return things
