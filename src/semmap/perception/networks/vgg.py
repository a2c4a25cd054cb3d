"""VGG-16 feature blocks (Simonyan & Zisserman 2015) with a width multiplier: five blocks of 2, 2, 3, 3, 3
3x3 conv + BN + ReLU layers.  BatchNorm is added (the papers' Caffe VGG-16 had none but started from ImageNet
weights) because semmap trains from scratch, where BN keeps a 13-layer plain stack trainable."""

from __future__ import annotations

from torch import nn

from semmap.perception.networks.layers import ConvBNReLU, scaled

#: (full-size channels, conv layers) of VGG-16's five blocks.
BLOCKS: tuple[tuple[int, int], ...] = ((64, 2), (128, 2), (256, 3), (512, 3), (512, 3))


def vgg_block(cin: int, channels: int, layers: int, *, dilation: int = 1) -> nn.Sequential:
    """``layers`` 3x3 conv + BN + ReLU (dilated by ``dilation``), the first from ``cin`` channels."""
    return nn.Sequential(*(ConvBNReLU(cin if i == 0 else channels, channels, 3, dilation=dilation)
                           for i in range(layers)))


def vgg16_widths(width: float) -> tuple[int, ...]:
    """Channels of the five blocks for width multiplier ``width``."""
    return tuple(scaled(c, width) for c, _ in BLOCKS)
