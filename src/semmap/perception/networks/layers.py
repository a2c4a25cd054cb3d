"""Building blocks shared by the segmentation networks: scaled widths, conv + BN + ReLU, depthwise-separable
convolution, ONNX-friendly adaptive average pooling and bilinear resizing."""

from __future__ import annotations

import torch
import torch.nn.functional as F  # noqa: N812  (the usual PyTorch alias)
from torch import nn

#: Narrowest layer a width multiplier may produce (keeps tiny variants trainable).
MIN_CHANNELS = 8


def scaled(channels: int, width: float) -> int:
    """``channels`` times the width multiplier, rounded to a multiple of 4 and at least :data:`MIN_CHANNELS`."""
    if width <= 0:
        raise ValueError(f"width multiplier must be positive, got {width}")
    return max(MIN_CHANNELS, round(channels * width / 4.0) * 4)


class ConvBNReLU(nn.Sequential):
    """k x k convolution (optionally dilated / strided) + BatchNorm + ReLU."""

    def __init__(self, cin: int, cout: int, k: int = 3, *, stride: int = 1, dilation: int = 1) -> None:
        super().__init__(nn.Conv2d(cin, cout, k, stride, padding=dilation * (k // 2), dilation=dilation, bias=False),
                         nn.BatchNorm2d(cout), nn.ReLU(inplace=True))


class SeparableConvBNReLU(nn.Sequential):
    """Depthwise-separable 3x3 convolution (Chollet 2017; rgbd-semantic-mapping Fig. 4): a per-channel 3x3
    (dilated) convolution, then a 1x1 pointwise convolution across channels, BN + ReLU after each."""

    def __init__(self, cin: int, cout: int, *, dilation: int = 1) -> None:
        super().__init__(nn.Conv2d(cin, cin, 3, padding=dilation, dilation=dilation, groups=cin, bias=False),
                         nn.BatchNorm2d(cin), nn.ReLU(inplace=True),
                         nn.Conv2d(cin, cout, 1, bias=False), nn.BatchNorm2d(cout), nn.ReLU(inplace=True))


def pooling_matrix(size: int, bins: int, dtype: torch.dtype = torch.float32) -> torch.Tensor:
    """(bins, size) averaging weights of adaptive average pooling along one axis: bin i covers
    [floor(i size / bins), ceil((i + 1) size / bins)), exactly as ``nn.AdaptiveAvgPool2d`` does."""
    m = torch.zeros(bins, size, dtype=dtype)
    for i in range(bins):
        lo, hi = (i * size) // bins, -((-(i + 1) * size) // bins)
        m[i, lo:hi] = 1.0 / (hi - lo)
    return m


def adaptive_avg_pool(x: torch.Tensor, bins: int) -> torch.Tensor:
    """``F.adaptive_avg_pool2d(x, bins)`` written as two matrix products, so it exports to ONNX for any input
    size (the ONNX exporter rejects adaptive pooling whose bins do not divide the feature map)."""
    h, w = int(x.shape[-2]), int(x.shape[-1])
    ph = pooling_matrix(h, bins, x.dtype).to(x.device)
    pw = pooling_matrix(w, bins, x.dtype).to(x.device)
    return torch.matmul(torch.matmul(ph, x), pw.t())


def resize(x: torch.Tensor, size: tuple[int, int] | torch.Size) -> torch.Tensor:
    """Bilinear resize of feature maps to ``size`` (h, w) with ``align_corners=False`` (the segmenter's convention)."""
    return F.interpolate(x, size=(int(size[0]), int(size[1])), mode="bilinear", align_corners=False)


def init_weights(module: nn.Module) -> None:
    """He-normal convolutions, unit BatchNorm: training from scratch starts well conditioned."""
    for m in module.modules():
        if isinstance(m, nn.Conv2d):
            nn.init.kaiming_normal_(m.weight, mode="fan_out", nonlinearity="relu")
            if m.bias is not None:
                nn.init.zeros_(m.bias)
        elif isinstance(m, nn.BatchNorm2d):
            nn.init.ones_(m.weight)
            nn.init.zeros_(m.bias)
