"""torchvision's detection models without its compiled operators: pure-torch CPU kernels for the two it needs.

The torchvision wheel installed beside our CPU torch is a CUDA build: its ``_C`` library needs libtorch_cuda, so it
does not load, and ``import torchvision`` then fails on registering fake kernels for operators that were never
defined ("operator torchvision::nms does not exist"). Mask R-CNN needs only two of those operators at inference:
``nms`` (non-maximum suppression) and ``roi_align`` (bilinear pooling of box regions). When the compiled library
does not load, :func:`import_torchvision` defines their schemas in the ``torchvision`` operator namespace with CPU
kernels written in torch (``roi_align`` is torchvision's own pure-torch version, run eagerly instead of through
``torch.compile``), declares ``qnms`` (whose fake kernel torchvision registers on import) and then imports
torchvision and tells it that its operators are there. Where the compiled library loads, nothing is replaced.
"""

from __future__ import annotations

import importlib.util
import inspect
import sys
from pathlib import Path

import numpy as np
import torch

from semmap.errors import ConfigError

#: Keeps the operator definitions alive (they are removed when the library object is collected).
_LIBRARY: torch.library.Library | None = None


#: How to get torchvision, which semmap does not install by default: PyPI's build does not import beside the CPU
#: torch semmap pins ("operator torchvision::nms does not exist"), and where it is installed transformers imports it,
#: so that a user's own SegFormer would not load either. semmap supplies the two operators Mask R-CNN needs.
INSTALL = "pip install 'semmap[maskrcnn]' (torchvision 0.28.0; semmap supplies the compiled operators it lacks)"


def import_torchvision(needed_by: str = "--instances maskrcnn"):
    """The ``torchvision`` module, with working ``nms`` and ``roi_align`` on the CPU (see the module docstring);
    without torchvision, one ConfigError line saying what ``needed_by`` needs and how to install it."""
    if "torchvision.ops" in sys.modules:
        return sys.modules["torchvision"]
    spec = importlib.util.find_spec("torchvision")
    if spec is None or not spec.submodule_search_locations:
        raise ConfigError(f"{needed_by} needs torchvision, which semmap does not install by default: {INSTALL}")
    native = _load_native(Path(next(iter(spec.submodule_search_locations))))
    if not native and _LIBRARY is None:
        _define_operators()
    import torchvision

    if not native:
        torchvision.extension._has_ops = lambda: True  # the operators exist now, as kernels of ours
        roi_align_module = sys.modules["torchvision.ops.roi_align"]
        roi_align_module._has_ops = lambda: True
        _LIBRARY.impl("roi_align", inspect.unwrap(roi_align_module._roi_align), "CPU")
    return torchvision


def _load_native(folder: Path) -> bool:
    """Whether torchvision's compiled operators load (a CPU build of torchvision, or CUDA libraries present)."""
    for lib in sorted(folder.glob("_C*.so")) + sorted(folder.glob("_C*.pyd")):
        try:
            torch.ops.load_library(str(lib))
            return True
        except (OSError, RuntimeError):
            return False
    return False


def _define_operators() -> None:
    global _LIBRARY
    lib = torch.library.Library("torchvision", "DEF")
    lib.define("nms(Tensor dets, Tensor scores, float iou_threshold) -> Tensor")
    lib.define("qnms(Tensor dets, Tensor scores, float iou_threshold) -> Tensor")
    lib.define("roi_align(Tensor input, Tensor rois, float spatial_scale, SymInt pooled_height, "
               "SymInt pooled_width, int sampling_ratio, bool aligned) -> Tensor")
    lib.impl("nms", nms, "CPU")
    _LIBRARY = lib


def nms(boxes: torch.Tensor, scores: torch.Tensor, iou_threshold: float) -> torch.Tensor:
    """Indices of the boxes (K, 4) ``x0, y0, x1, y1`` kept by greedy non-maximum suppression, by decreasing score:
    a box goes when its IoU with a kept, higher-scoring box exceeds ``iou_threshold`` (torchvision's semantics)."""
    if boxes.numel() == 0:
        return torch.empty(0, dtype=torch.long)
    order = torch.argsort(scores, descending=True, stable=True)
    b = boxes[order].double()
    area = (b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1])
    lt = torch.maximum(b[:, None, :2], b[None, :, :2])
    rb = torch.minimum(b[:, None, 2:], b[None, :, 2:])
    wh = (rb - lt).clamp(min=0)
    inter = wh[..., 0] * wh[..., 1]
    over = (inter / (area[:, None] + area[None, :] - inter) > iou_threshold).numpy()
    suppressed = np.zeros(len(b), bool)
    keep = []
    for i in range(len(b)):  # greedy and sequential by nature; the IoUs are computed once above
        if not suppressed[i]:
            keep.append(i)
            suppressed |= over[i]
    return order[torch.as_tensor(keep, dtype=torch.long)]
