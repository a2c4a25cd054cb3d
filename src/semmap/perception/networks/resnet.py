"""ResNet-18/34/50 backbones (He et al. 2016) with a width multiplier, optional dilation (output stride 8 or 16,
as PSPNet uses them) and an optional attention module on every residual branch (CBAM-PSPNet, Fig. 3).

Written here because torchvision's compiled operators do not load in semmap's CPU environment; the layout is the
standard one (7x7 stem, max pool, four stages of basic or bottleneck blocks), so full-size variants
(``width=1``) have the usual parameter counts (ResNet-50 without its classifier: 23.5 M).
"""

from __future__ import annotations

from collections.abc import Callable

import torch
from torch import nn

from semmap.perception.networks.layers import scaled

#: depth -> (block kind, blocks per stage).
LAYOUTS: dict[int, tuple[str, tuple[int, int, int, int]]] = {
    18: ("basic", (2, 2, 2, 2)), 34: ("basic", (3, 4, 6, 3)), 50: ("bottleneck", (3, 4, 6, 3)),
}
#: Stage widths of the full-size networks (bottleneck blocks expand them 4x at their output).
STAGE_WIDTHS = (64, 128, 256, 512)
BOTTLENECK_EXPANSION = 4
#: output stride -> (stride, dilation) of stages 3 and 4.
OUTPUT_STRIDES: dict[int, tuple[tuple[int, int], tuple[int, int]]] = {
    32: ((2, 1), (2, 1)), 16: ((2, 1), (1, 2)), 8: ((1, 2), (1, 4)),
}

AttentionFactory = Callable[[int], nn.Module] | None


class BasicBlock(nn.Module):
    """Two 3x3 convolutions on the residual branch (ResNet-18/34); ``attention`` reweights the branch output
    before the shortcut is added."""

    expansion = 1

    def __init__(self, cin: int, planes: int, stride: int, dilation: int, attention: AttentionFactory) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(cin, planes, 3, stride, padding=dilation, dilation=dilation, bias=False)
        self.bn1 = nn.BatchNorm2d(planes)
        self.conv2 = nn.Conv2d(planes, planes, 3, 1, padding=dilation, dilation=dilation, bias=False)
        self.bn2 = nn.BatchNorm2d(planes)
        self.relu = nn.ReLU(inplace=True)
        self.attention = attention(planes) if attention is not None else None
        self.shortcut = _shortcut(cin, planes, stride)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """relu(attention(branch(x)) + shortcut(x))."""
        y = self.relu(self.bn1(self.conv1(x)))
        y = self.bn2(self.conv2(y))
        if self.attention is not None:
            y = self.attention(y)
        return self.relu(y + (x if self.shortcut is None else self.shortcut(x)))


class Bottleneck(nn.Module):
    """1x1 reduce, 3x3 (strided / dilated), 1x1 expand x4 (ResNet-50)."""

    expansion = BOTTLENECK_EXPANSION

    def __init__(self, cin: int, planes: int, stride: int, dilation: int, attention: AttentionFactory) -> None:
        super().__init__()
        cout = planes * self.expansion
        self.conv1 = nn.Conv2d(cin, planes, 1, bias=False)
        self.bn1 = nn.BatchNorm2d(planes)
        self.conv2 = nn.Conv2d(planes, planes, 3, stride, padding=dilation, dilation=dilation, bias=False)
        self.bn2 = nn.BatchNorm2d(planes)
        self.conv3 = nn.Conv2d(planes, cout, 1, bias=False)
        self.bn3 = nn.BatchNorm2d(cout)
        self.relu = nn.ReLU(inplace=True)
        self.attention = attention(cout) if attention is not None else None
        self.shortcut = _shortcut(cin, cout, stride)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """relu(attention(branch(x)) + shortcut(x))."""
        y = self.relu(self.bn1(self.conv1(x)))
        y = self.relu(self.bn2(self.conv2(y)))
        y = self.bn3(self.conv3(y))
        if self.attention is not None:
            y = self.attention(y)
        return self.relu(y + (x if self.shortcut is None else self.shortcut(x)))


def _shortcut(cin: int, cout: int, stride: int) -> nn.Module | None:
    """Identity, or a strided 1x1 projection + BN where the shape changes."""
    if stride == 1 and cin == cout:
        return None
    return nn.Sequential(nn.Conv2d(cin, cout, 1, stride, bias=False), nn.BatchNorm2d(cout))


class ResNet(nn.Module):
    """ResNet feature extractor returning the outputs of its four stages (strides 4, 8, and per
    ``output_stride`` 8/16/32 for stages 3 and 4); ``channels`` lists their widths."""

    def __init__(self, depth: int = 18, *, width: float = 1.0, output_stride: int = 32,
                 attention: AttentionFactory = None, in_channels: int = 3) -> None:
        super().__init__()
        if depth not in LAYOUTS:
            raise ValueError(f"ResNet depth must be one of {sorted(LAYOUTS)}, got {depth}")
        if output_stride not in OUTPUT_STRIDES:
            raise ValueError(f"output stride must be one of {sorted(OUTPUT_STRIDES)}, got {output_stride}")
        kind, counts = LAYOUTS[depth]
        block = BasicBlock if kind == "basic" else Bottleneck
        stem = scaled(64, width)
        self.stem = nn.Sequential(nn.Conv2d(in_channels, stem, 7, 2, padding=3, bias=False), nn.BatchNorm2d(stem),
                                  nn.ReLU(inplace=True), nn.MaxPool2d(3, 2, padding=1))
        (s3, d3), (s4, d4) = OUTPUT_STRIDES[output_stride]
        plan = ((1, 1), (2, 1), (s3, d3), (s4, d4))
        cin, dilation = stem, 1
        stages, channels = [], []
        for (stride, new_dilation), n, planes in zip(plan, counts, (scaled(c, width) for c in STAGE_WIDTHS),
                                                     strict=True):
            blocks = []
            for i in range(n):
                # the first block of a dilated stage keeps the previous dilation (no gridding at its entry)
                blocks.append(block(cin, planes, stride if i == 0 else 1, dilation if i == 0 else new_dilation,
                                    attention))
                cin = planes * block.expansion
            dilation = new_dilation
            stages.append(nn.Sequential(*blocks))
            channels.append(cin)
        self.layer1, self.layer2, self.layer3, self.layer4 = stages
        self.channels = tuple(channels)

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """Features of stages 1-4."""
        c1 = self.layer1(self.stem(x))
        c2 = self.layer2(c1)
        c3 = self.layer3(c2)
        return c1, c2, c3, self.layer4(c3)
