"""Convolutional Block Attention Module (Woo et al. 2018), as CBAM-PSPNet embeds it (semantic-octomap-cbam-pspnet,
eqs. 1-2, Fig. 3): channel attention, then spatial attention, applied to a residual branch before the shortcut add."""

from __future__ import annotations

import torch
from torch import nn

#: Reduction ratio r of the shared MLP (hidden = C / r), as in CBAM.
REDUCTION = 16
#: Narrowest hidden layer of the shared MLP (small width multipliers would otherwise leave 1-2 units).
MIN_HIDDEN = 4
#: Kernel of the spatial attention convolution f^{7x7} (eq. 2).
SPATIAL_KERNEL = 7


class ChannelAttention(nn.Module):
    """M_c(F) = sigma(W1 W0 F_avg + W1 W0 F_max) (eq. 1): one weight per channel from a shared two-layer MLP
    over the globally average- and max-pooled descriptors."""

    def __init__(self, channels: int, reduction: int = REDUCTION) -> None:
        super().__init__()
        hidden = max(MIN_HIDDEN, channels // reduction)
        self.mlp = nn.Sequential(nn.Conv2d(channels, hidden, 1, bias=False), nn.ReLU(inplace=True),
                                 nn.Conv2d(hidden, channels, 1, bias=False))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """(N, C, 1, 1) channel weights in (0, 1)."""
        avg = x.mean(dim=(2, 3), keepdim=True)
        mx = x.amax(dim=(2, 3), keepdim=True)
        return torch.sigmoid(self.mlp(avg) + self.mlp(mx))


class SpatialAttention(nn.Module):
    """M_s(F) = sigma(f^{7x7}([F_avg; F_max])) (eq. 2): one weight per pixel from a 7x7 convolution over the
    channel-wise average and maximum."""

    def __init__(self, kernel: int = SPATIAL_KERNEL) -> None:
        super().__init__()
        self.conv = nn.Conv2d(2, 1, kernel, padding=kernel // 2, bias=False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """(N, 1, H, W) pixel weights in (0, 1)."""
        desc = torch.cat([x.mean(dim=1, keepdim=True), x.amax(dim=1, keepdim=True)], dim=1)
        return torch.sigmoid(self.conv(desc))


class CBAM(nn.Module):
    """F' = M_c(F) * F, F'' = M_s(F') * F' (Fig. 3)."""

    def __init__(self, channels: int, reduction: int = REDUCTION) -> None:
        super().__init__()
        self.channel = ChannelAttention(channels, reduction)
        self.spatial = SpatialAttention()

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """The feature map reweighted by channel, then by position."""
        x = x * self.channel(x)
        return x * self.spatial(x)
