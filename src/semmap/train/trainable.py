"""The networks ``semmap adapt`` can fine-tune, behind one face: semmap's own (``weights/*.pt`` and any ``semmap
train`` run's, :mod:`semmap.perception.networks`) and the PASCAL VOC ESPNetv2 (its authors' state dict, shipped in
``weights/espnetv2/``).

Training ids: 0 teaches nothing (the trainer's ignore index), every other id a class of the network. semmap's
networks keep id 0 for "unknown" already; ESPNetv2's class 0 is VOC's *background*, a class it must keep
learning, so its classes move up by one and the training logits get a first channel that never wins."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import torch
import torch.nn.functional as F  # noqa: N812  (the usual PyTorch alias)

from semmap.errors import ConfigError
from semmap.train.class_weights import IGNORE
from semmap.types import LabelSet

#: The logit of the training channel that stands for "teaches nothing" (never the top class).
NEVER = -1e4


@dataclass
class Trainable:
    """A network as adaptation trains it: ``model.forward_train(image, depth)`` gives (logits at the input size
    over the training ids, auxiliary logits or None); ``save(path, meta)`` writes the file its segmenter reads."""

    name: str  #: the segmenter (``fcn``, ``espnetv2``)
    network: str  #: what it is, with its size (``fcn-espnetv2-s1-w0.25``)
    model: torch.nn.Module
    label_set: LabelSet  #: over the training ids (id 0: teaches nothing)
    uses_depth: bool
    meta: dict
    input_for: Callable[[int, int], tuple[int, int]]  #: (frame width, height) -> (input width, height)
    interpolation: int  #: how the segmenter reduces colour images (cv2 flag)
    save: Callable[[Path, dict], Path]
    suffix: str  #: of its weight files
    spec: dict
    #: map label set -> (K_map,) training id of each map class (by name unless the network says otherwise)
    classes_of: Callable[[LabelSet, LabelSet], np.ndarray] | None = None

    def lut(self, map_labels: LabelSet) -> np.ndarray:
        """Map class id -> training id (0: the network has no such class, or the map's own "unknown")."""
        lut = (self.classes_of or by_name)(map_labels, self.label_set).copy()
        lut[IGNORE] = IGNORE
        if not (lut != IGNORE).any():
            raise ConfigError(f"the map's classes ({', '.join(map_labels.names[1:6])}, ...) share none with "
                              f"{self.name}'s ({', '.join(self.label_set.names[1:6])}, ...): nothing to teach")
        return lut


def by_name(map_labels: LabelSet, training: LabelSet) -> np.ndarray:
    """Each map class's training id: the network's class of the same name, else 0."""
    index = {name: i for i, name in enumerate(training.names)}
    return np.array([index.get(name, IGNORE) for name in map_labels.names], np.int64)


def load_trainable(segmenter: str, weights: Path) -> Trainable:
    """The network of segmenter ``segmenter`` with the weights in ``weights``, ready to train."""
    from semmap.perception.registry import ESPNETV2

    if segmenter == ESPNETV2:
        return _espnetv2(weights)
    from semmap.perception.networks.registry import load_weights, save_weights

    net = load_weights(weights)
    size = tuple(net.input_size)

    def save(path: Path, meta: dict) -> Path:
        return save_weights(path, net.model, net.spec, net.label_set, net.input_size, meta)

    return Trainable(name=net.spec.model, network=net.spec.describe(), model=net.model, label_set=net.label_set,
                     uses_depth=net.spec.uses_depth, meta=dict(net.meta), input_for=lambda w, h: size,
                     interpolation=cv2.INTER_AREA, save=save, suffix=".pt", spec=net.spec.to_dict())


class _ShiftedClasses(torch.nn.Module):
    """A network whose class 0 is a real class, trained with its classes moved up one: channel 0 of the training
    logits is :data:`NEVER`, and the logits are upsampled to the input size as the segmenter samples them."""

    def __init__(self, net: torch.nn.Module) -> None:
        super().__init__()
        self.net = net
        self.align = bool(getattr(net, "logits_align_corners", False))

    def forward_train(self, image: torch.Tensor, depth: torch.Tensor | None = None):
        logits = F.interpolate(self.net(image), image.shape[-2:], mode="bilinear", align_corners=self.align)
        return torch.cat([torch.full_like(logits[:, :1], NEVER), logits], 1), None


def _espnetv2(weights: Path) -> Trainable:
    """The PASCAL VOC ESPNetv2 at its segmenter's input (short side 320, linear reduction); the map's classes
    reach VOC's through the fold of ``NAME+structure`` read backwards, every other class of the map is VOC's
    background (a wall, a cabinet: what VOC calls background)."""
    from semmap.perception.espnetv2 import espnetv2_meta, load_espnetv2, save_espnetv2
    from semmap.perception.network import NetworkInput
    from semmap.perception.registry import ESPNETV2, ESPNETV2_INPUT
    from semmap.perception.voc import PASCAL_VOC

    inner = load_espnetv2(weights, full_resolution=False)
    names = ("unknown", *PASCAL_VOC.names)
    colors = np.concatenate([np.zeros((1, 3), np.uint8), np.asarray(PASCAL_VOC.colors, np.uint8)])
    net_input = NetworkInput(short_side=ESPNETV2_INPUT)

    def save(path: Path, meta: dict) -> Path:
        return save_espnetv2(path, inner, meta)

    return Trainable(name=ESPNETV2, network=f"espnetv2-s{inner.s:g}-voc", model=_ShiftedClasses(inner),
                     label_set=LabelSet(names, colors), uses_depth=False, meta=espnetv2_meta(weights),
                     input_for=net_input.size_for, interpolation=net_input.interpolation, save=save, suffix=".pth",
                     spec={"model": ESPNETV2, "s": inner.s, "num_classes": inner.num_classes},
                     classes_of=_voc_classes)


def _voc_classes(map_labels: LabelSet, training: LabelSet) -> np.ndarray:
    """Map class -> ESPNetv2 training id: the VOC class folding into it (``NAME+structure``'s fold read
    backwards), else VOC's background; the map's "unknown" teaches nothing."""
    from semmap.labels import INDOOR_LABELS
    from semmap.perception.structure.compose import fold_to
    from semmap.perception.voc import PASCAL_VOC

    indoor = tuple(map_labels.names) == tuple(INDOOR_LABELS.names)  # (the shipped fold is for semmap's classes)
    fold, _ = fold_to(PASCAL_VOC, INDOOR_LABELS if indoor else map_labels)
    background = 1  # VOC class 0, moved up one
    lut = np.full(len(map_labels), background, np.int64)
    for voc_id in range(len(PASCAL_VOC) - 1, 0, -1):  # the first VOC class of each map class wins
        if fold[voc_id]:
            lut[int(fold[voc_id])] = voc_id + 1
    return lut
