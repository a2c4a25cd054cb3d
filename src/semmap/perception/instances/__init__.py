"""Instance sources: per frame, object masks with a class, a score and optionally an appearance feature
(:class:`~semmap.types.Instances`), from the simulator's instance images (``oracle``), connected components of a
semantic segmentation (``components``) or torchvision's Mask R-CNN (``maskrcnn``)."""

from semmap.perception.instances.base import InstanceSource, thing_classes
from semmap.perception.instances.registry import INSTANCE_SOURCES, make_instance_source

__all__ = ["INSTANCE_SOURCES", "InstanceSource", "make_instance_source", "thing_classes"]
