"""FCN-8s (Long et al. 2015): class scores from three depths of a backbone (strides 8, 16, 32) fused coarse to
fine - score_32 upsampled x2 plus score_16, upsampled x2 plus score_8 - then bilinearly upsampled to the image.

The backbone is a ResNet (default, the same one PSPNet dilates, so the two differ only in their heads) or
VGG-16 with its fully connected fc6/fc7 turned into convolutions (3x3 and 1x1 here, 1024 channels at full size,
instead of FCN's 7x7 and 4096: the same role at a size a CPU trains).  The 2x upsamplings are fixed bilinear
(FCN initialised its deconvolutions to bilinear; fixed, every input size works, also sizes not divisible by 32).
"""

from __future__ import annotations

import torch
from torch import nn

from semmap.perception.networks.base import SegmentationNet
from semmap.perception.networks.layers import ConvBNReLU, init_weights, resize, scaled
from semmap.perception.networks.resnet import ResNet
from semmap.perception.networks.vgg import BLOCKS, vgg16_widths, vgg_block

BACKBONES = ("resnet", "vgg16")
#: fc6/fc7 width of the VGG variant at full size.
VGG_FC_CHANNELS = 1024


class VGGFeatures(nn.Module):
    """VGG-16 blocks with their max pools, returning the pool3, pool4 and fc7 features (strides 8, 16, 32)."""

    def __init__(self, width: float, in_channels: int = 3) -> None:
        super().__init__()
        widths = vgg16_widths(width)
        blocks, cin = [], in_channels
        for (_, layers), c in zip(BLOCKS, widths, strict=True):
            blocks.append(vgg_block(cin, c, layers))
            cin = c
        self.blocks = nn.ModuleList(blocks)
        self.pool = nn.MaxPool2d(2, 2, ceil_mode=True)
        fc = scaled(VGG_FC_CHANNELS, width)
        self.fc = nn.Sequential(ConvBNReLU(cin, fc, 3), nn.Dropout2d(0.1), ConvBNReLU(fc, fc, 1))
        self.channels = (widths[2], widths[3], fc)

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        feats = []
        for block in self.blocks:
            x = self.pool(block(x))
            feats.append(x)
        return feats[2], feats[3], self.fc(feats[4])


class FCN8s(SegmentationNet):
    """FCN-8s over a ResNet-``depth`` or VGG-16 backbone with width multiplier ``width``."""

    def __init__(self, num_classes: int, *, backbone: str = "resnet", depth: int = 18, width: float = 1.0,
                 full_resolution: bool = False) -> None:
        super().__init__(num_classes, full_resolution=full_resolution)
        if backbone not in BACKBONES:
            raise ValueError(f"FCN backbone must be one of {BACKBONES}, got {backbone!r}")
        self.backbone_kind = backbone
        if backbone == "resnet":
            self.backbone = ResNet(depth, width=width, output_stride=32)
            c8, c16, c32 = self.backbone.channels[1:]
        else:
            self.backbone = VGGFeatures(width)
            c8, c16, c32 = self.backbone.channels
        self.score8 = nn.Conv2d(c8, num_classes, 1)
        self.score16 = nn.Conv2d(c16, num_classes, 1)
        self.score32 = nn.Conv2d(c32, num_classes, 1)
        init_weights(self)

    def heads(self, image: torch.Tensor, depth: torch.Tensor | None) -> tuple[torch.Tensor, None]:
        if self.backbone_kind == "resnet":
            _, f8, f16, f32 = self.backbone(image)
        else:
            f8, f16, f32 = self.backbone(image)
        s16 = self.score16(f16) + resize(self.score32(f32), f16.shape[-2:])
        s8 = self.score8(f8) + resize(s16, f8.shape[-2:])
        return s8, None
