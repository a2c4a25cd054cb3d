"""The RGB-D segmentation network of rgbd-semantic-mapping-multiscale-crf (Sec. 2.1, Figs. 2-4).

* Primary branch (colour): VGG-16 blocks 1-5, pool5 removed, every conv5 layer dilated by 2.
* Sub-branch (depth): VGG-16 blocks 1-4 (conv5 removed), on the depth image.
* Fusion step by step (Fig. 2): after each of blocks 1-4 the depth features are added to the colour features
  (element-wise, FuseNet-style) before both are pooled; block 5 then runs on the fused features.
* Multi-scale feature fusion module (Fig. 3) on the stride-16 features: parallel 1x1, 3x3, two stacked 3x3 (a
  5x5 factored) and 3x3-max-pool + 1x1 branches, every 3x3 convolution dilated (12 in the paper) and
  depthwise-separable (Fig. 4), concatenated, then a 1x1 classifier.

``use_depth=False`` gives the colour-only twin the paper compares against (Tables 2-3): the same network without
the sub-branch.  Depth is encoded as in the paper, one channel of metric depth (normalised here to zero mean and
unit spread over indoor ranges, invalid pixels set to 0 after normalisation); HHA is not used.

The module's 3x3 dilation is relative to the feature map: the paper's 12 at stride 16 of a 480x360 input covers
about half of a 30x23 map.  Small inputs take a proportionally smaller dilation (see ``msff_dilation``).
"""

from __future__ import annotations

import torch
from torch import nn

from semmap.perception.networks.base import SegmentationNet
from semmap.perception.networks.layers import ConvBNReLU, SeparableConvBNReLU, init_weights, scaled
from semmap.perception.networks.vgg import BLOCKS, vgg16_widths, vgg_block

#: Dilation of conv5 in the colour branch and of the fusion module's 3x3 convolutions (paper values).
CONV5_DILATION = 2
MSFF_DILATION = 12
#: Channels of each fusion-module branch at full size.
BRANCH_CHANNELS = 256
#: Depth normalisation (metres): indoor depth is mostly 0.5-5 m.
DEPTH_MEAN_M = 2.5
DEPTH_STD_M = 1.5
DROPOUT = 0.1


class MultiScaleFusion(nn.Module):
    """Fig. 3: four parallel branches of different receptive fields over the same features, concatenated."""

    def __init__(self, cin: int, branch: int, dilation: int) -> None:
        super().__init__()
        self.b1 = ConvBNReLU(cin, branch, 1)
        self.b3 = SeparableConvBNReLU(cin, branch, dilation=dilation)
        self.b5 = nn.Sequential(SeparableConvBNReLU(cin, branch, dilation=dilation),
                                SeparableConvBNReLU(branch, branch, dilation=dilation))
        self.pool = nn.Sequential(nn.MaxPool2d(3, 1, padding=1), ConvBNReLU(cin, branch, 1))
        self.out_channels = 4 * branch

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return torch.cat([self.b1(x), self.b3(x), self.b5(x), self.pool(x)], dim=1)


class RGBDNet(SegmentationNet):
    """Two-branch VGG-16 RGB-D network with step-by-step fusion and the multi-scale fusion module."""

    def __init__(self, num_classes: int, *, width: float = 1.0, use_depth: bool = True,
                 msff_dilation: int = MSFF_DILATION, full_resolution: bool = False) -> None:
        super().__init__(num_classes, full_resolution=full_resolution)
        if msff_dilation < 1:
            raise ValueError(f"fusion-module dilation must be at least 1, got {msff_dilation}")
        self.uses_depth = use_depth
        widths = vgg16_widths(width)
        layers = [n for _, n in BLOCKS]
        cin = 3
        self.color = nn.ModuleList()
        for i, (c, n) in enumerate(zip(widths, layers, strict=True)):
            self.color.append(vgg_block(cin, c, n, dilation=CONV5_DILATION if i == 4 else 1))
            cin = c
        if use_depth:
            self.depth = nn.ModuleList()
            cin = 1
            for c, n in zip(widths[:4], layers[:4], strict=True):
                self.depth.append(vgg_block(cin, c, n))
                cin = c
        self.pool = nn.MaxPool2d(2, 2, ceil_mode=True)
        self.fusion = MultiScaleFusion(widths[4], scaled(BRANCH_CHANNELS, width), msff_dilation)
        self.classifier = nn.Sequential(nn.Dropout2d(DROPOUT), nn.Conv2d(self.fusion.out_channels, num_classes, 1))
        init_weights(self)

    def heads(self, image: torch.Tensor, depth: torch.Tensor | None) -> tuple[torch.Tensor, None]:
        self._check_depth(depth)
        x = image
        d = None
        if self.uses_depth:
            d = torch.where(depth > 0, (depth - DEPTH_MEAN_M) / DEPTH_STD_M, torch.zeros_like(depth))
        for i in range(4):
            x = self.color[i](x)
            if d is not None:
                d = self.depth[i](d)
                x = x + d  # step-by-step fusion of geometry into colour
                d = self.pool(d)
            x = self.pool(x)
        x = self.color[4](x)  # dilated conv5 on the fused features, stride 16 (pool5 removed)
        return self.classifier(self.fusion(x)), None
