"""PSPNet (Zhao et al. 2017): a dilated ResNet (output stride 8), the pyramid pooling module (average pooling to
1x1, 2x2, 3x3 and 6x6 bins, 1x1 reduction to C/4 each, upsampled and concatenated with the features), a 3x3
conv + dropout + 1x1 classifier, and an auxiliary classifier on stage 3 used only in training (loss weight 0.4).

``attention`` puts a module (CBAM for CBAM-PSPNet) on every residual branch of the backbone.
"""

from __future__ import annotations

import torch
from torch import nn

from semmap.perception.networks.base import SegmentationNet
from semmap.perception.networks.layers import ConvBNReLU, adaptive_avg_pool, init_weights, resize, scaled
from semmap.perception.networks.resnet import AttentionFactory, ResNet

#: Pyramid bins of the pyramid pooling module.
PYRAMID_BINS = (1, 2, 3, 6)
#: Weight of the auxiliary (stage-3) loss in training.
AUX_WEIGHT = 0.4
#: Head widths at full size: the 3x3 conv after the pyramid, and the auxiliary head.
HEAD_CHANNELS = 512
AUX_CHANNELS = 256
DROPOUT = 0.1


class PyramidPooling(nn.Module):
    """Concatenation of the features with their average-pooled, 1x1-reduced and upsampled pyramid levels."""

    def __init__(self, channels: int, bins: tuple[int, ...] = PYRAMID_BINS) -> None:
        super().__init__()
        self.bins = bins
        reduced = max(channels // len(bins), 1)
        self.reduce = nn.ModuleList(ConvBNReLU(channels, reduced, 1) for _ in bins)
        self.out_channels = channels + reduced * len(bins)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        size = x.shape[-2:]
        return torch.cat([x, *(resize(conv(adaptive_avg_pool(x, b)), size)
                               for b, conv in zip(self.bins, self.reduce, strict=True))], dim=1)


def pyramid_heads(c3: int, c4: int, num_classes: int, width: float) -> tuple[PyramidPooling, nn.Sequential,
                                                                            nn.Sequential]:
    """PSPNet's pyramid pooling over the last level (``c4`` channels), its classifier head and the auxiliary head
    on the level before (``c3``), sized by ``width``: one recipe for every encoder it sits on."""
    ppm = PyramidPooling(c4)
    head = scaled(HEAD_CHANNELS, width)
    main = nn.Sequential(ConvBNReLU(ppm.out_channels, head, 3), nn.Dropout2d(DROPOUT), nn.Conv2d(head, num_classes, 1))
    aux = scaled(AUX_CHANNELS, width)
    return ppm, main, nn.Sequential(ConvBNReLU(c3, aux, 3), nn.Dropout2d(DROPOUT), nn.Conv2d(aux, num_classes, 1))


class PSPNet(SegmentationNet):
    """PSPNet over a dilated ResNet-``depth`` (18, 34 or 50) with width multiplier ``width``."""

    def __init__(self, num_classes: int, *, depth: int = 50, width: float = 1.0, output_stride: int = 8,
                 attention: AttentionFactory = None, full_resolution: bool = False) -> None:
        super().__init__(num_classes, full_resolution=full_resolution)
        self.backbone = ResNet(depth, width=width, output_stride=output_stride, attention=attention)
        self.ppm, self.head, self.aux = pyramid_heads(*self.backbone.channels[2:], num_classes, width)
        init_weights(self)

    def heads(self, image: torch.Tensor, depth: torch.Tensor | None) -> tuple[torch.Tensor, torch.Tensor | None]:
        _, _, c3, c4 = self.backbone(image)
        logits = self.head(self.ppm(c4))
        return logits, (self.aux(c3) if self.training else None)
