"""Mask R-CNN instances (the paper's detector): torchvision's ``maskrcnn_resnet50_fpn`` with the user's weights.

No pretrained weights can be downloaded here, so the weights come from ``--instance-weights`` (a state dict of
``maskrcnn_resnet50_fpn`` or ``maskrcnn_resnet50_fpn_v2``; the class count is read from it). With 91 classes the
label set is torchvision's COCO categories; otherwise a ``labelset.json`` beside the weights names the classes, or
they are called ``class_i``. The network sees the colour camera's own image where the frame keeps one, and the
masks are carried onto the depth grid like every segmentation. Masks are pasted by decreasing score, so where two
overlap the more confident keeps the pixel. Appearance features for the tracker are the box head's 1024-d
representation of each final box (what DeepSORT's re-identification network provides).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from semmap.errors import ConfigError, FormatError
from semmap.geometry import onto_depth_grid
from semmap.types import Frame, Instances, LabelSet, TopKProbs, distinct_colors

#: Detections below this score are dropped (torchvision's own default box score threshold is 0.05).
SCORE_THRESHOLD = 0.5
#: Mask probability above which a pixel belongs to the instance.
MASK_THRESHOLD = 0.5


def build_maskrcnn(num_classes: int, *, v2: bool = False, **kwargs) -> torch.nn.Module:
    """An untrained ``maskrcnn_resnet50_fpn`` (or ``_v2``) with ``num_classes`` classes (background included)."""
    from semmap.perception.instances._torchvision_ops import import_torchvision

    detection = import_torchvision().models.detection
    make = detection.maskrcnn_resnet50_fpn_v2 if v2 else detection.maskrcnn_resnet50_fpn
    return make(weights=None, weights_backbone=None, num_classes=num_classes, **kwargs)


def coco_labels() -> LabelSet:
    """torchvision's 91 COCO categories (id 0 background, "N/A" for unused ids)."""
    from semmap.perception.instances._torchvision_ops import import_torchvision

    names = import_torchvision().models.detection.MaskRCNN_ResNet50_FPN_Weights.COCO_V1.meta["categories"]
    return LabelSet(("unknown", *names[1:]), distinct_colors(len(names)))


class MaskRcnnInstances:
    """:class:`~semmap.perception.instances.InstanceSource` running a torchvision Mask R-CNN on the CPU."""

    name = "maskrcnn"
    needs_semantics = False

    def __init__(self, model: torch.nn.Module, label_set: LabelSet, *, score_threshold: float = SCORE_THRESHOLD,
                 mask_threshold: float = MASK_THRESHOLD, features: bool = True) -> None:
        n_out = model.roi_heads.box_predictor.cls_score.out_features
        if n_out != len(label_set):
            raise ConfigError(f"Mask R-CNN predicts {n_out} classes but its label set has {len(label_set)}")
        self.model = model.eval()
        self._label_set = label_set
        self.score_threshold, self.mask_threshold = float(score_threshold), float(mask_threshold)
        self.features = features
        self._captured: dict[str, object] = {}
        model.backbone.register_forward_hook(lambda m, i, out: self._captured.__setitem__("features", out))
        model.transform.register_forward_hook(lambda m, i, out: self._captured.__setitem__("images", out[0]))

    @classmethod
    def from_weights(cls, path: str | Path, **kwargs) -> MaskRcnnInstances:
        """Load a ``maskrcnn_resnet50_fpn(_v2)`` state dict; the class count comes from the weights."""
        from semmap.perception.networks.registry import check_finite_tensors, read_torch_file

        path = Path(path)
        if not path.is_file():
            raise ConfigError(f"{path}: Mask R-CNN weights file not found")
        try:
            state = read_torch_file(path, "Mask R-CNN weights file")
            state = state.get("model", state) if isinstance(state, dict) else state
            check_finite_tensors(state, path)
        except FormatError as exc:
            raise ConfigError(str(exc)) from None
        key = "roi_heads.box_predictor.cls_score.weight"
        if not isinstance(state, dict) or key not in state:
            raise ConfigError(f"{path}: not a Mask R-CNN state dict (no {key})")
        num_classes = int(state[key].shape[0])
        model = build_maskrcnn(num_classes, v2="roi_heads.box_head.0.0.weight" in state)
        try:
            model.load_state_dict(state, strict=True)
        except RuntimeError as exc:
            raise ConfigError(f"{path}: weights do not fit maskrcnn_resnet50_fpn: {str(exc).splitlines()[0]}") \
                from None
        beside = path.with_name("labelset.json")
        if beside.is_file():
            label_set = LabelSet.load(beside)
        elif num_classes == 91:
            label_set = coco_labels()
        else:
            label_set = LabelSet.generic(num_classes)
        return cls(model, label_set, **kwargs)

    @property
    def label_set(self) -> LabelSet:
        return self._label_set

    def detect(self, frame: Frame, semantics: TopKProbs | None = None) -> Instances:
        """Instances of ``frame`` (``semantics`` is not used)."""
        image = frame.raw_color.image if frame.raw_color is not None else frame.rgb
        tensor = torch.from_numpy(np.ascontiguousarray(image)).permute(2, 0, 1).float().div_(255.0)
        with torch.inference_mode():
            out = self.model([tensor])[0]
            keep = out["scores"] >= self.score_threshold
            boxes, scores, classes = out["boxes"][keep], out["scores"][keep], out["labels"][keep]
            masks = out["masks"][keep, 0] > self.mask_threshold
            feats = self._box_features(boxes, image.shape[:2]) if self.features and len(boxes) else None
        ids = np.zeros(image.shape[:2], np.int32)
        order = np.argsort(-scores.numpy(), kind="stable")
        masks_np = masks.numpy()
        for rank, k in enumerate(order, 1):  # most confident first: it keeps the pixels two masks share
            ids[masks_np[k] & (ids == 0)] = rank
        cls = classes.numpy()[order].astype(np.int32)
        sc = scores.numpy()[order].astype(np.float32)
        fe = None if feats is None else feats[order]
        if frame.raw_color is not None:
            (ids,) = onto_depth_grid(frame, ids)
        return Instances.from_id_image(ids, cls, sc, fe)

    def _box_features(self, boxes: torch.Tensor, size: tuple[int, int]) -> np.ndarray:
        """(N, 1024) unit-length box-head representations of the final boxes (in original image pixels)."""
        images = self._captured["images"]
        h, w = images.image_sizes[0]
        scale = torch.tensor([w / size[1], h / size[0], w / size[1], h / size[0]], dtype=boxes.dtype)
        heads = self.model.roi_heads
        pooled = heads.box_roi_pool(self._captured["features"], [boxes * scale], images.image_sizes)
        rep = heads.box_head(pooled)
        return torch.nn.functional.normalize(rep, dim=1).numpy().astype(np.float32)
