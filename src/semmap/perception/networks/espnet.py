"""The papers' heads on the ESPNetv2 encoder (levels 1-4 of :class:`~semmap.perception.espnetv2.EESPNetEncoder`,
strides 2, 4, 8, 16), so that every architecture can start from the encoder trained on ImageNet and PASCAL VOC
(``semmap train --init espnetv2-pascal-s1``; :mod:`.pretrained` loads it).

* FCN-8s-style skip head: 1x1 class scores from levels 2, 3 and 4 (strides 4, 8, 16 - the encoder ends at 16,
  so the three depths sit one octave finer than FCN-8s's 8/16/32), fused coarse to fine by bilinear x2 upsampling
  and addition.
* PSPNet: the pyramid pooling module (bins 1/2/3/6) on level 4, 3x3 conv + dropout + 1x1 classifier, and the
  auxiliary classifier on level 3 (training only).
* CBAM-PSPNet: the same with a CBAM (channel then spatial attention, eqs. 1-2) on the residual branch of every
  residual EESP unit of levels 3 and 4 (before the shortcut add) and on the output of the strided units of levels
  2-4.  Each CBAM sits behind a scalar gate g initialised to 0: ``y + g (CBAM(y) - y)``, so at step 0 the encoder
  computes exactly the pretrained function, and g = 1 is the paper's block.
* RGB-D net: the pretrained colour encoder plus a depth branch (four stages of a strided and a plain 3x3 conv +
  BN + ReLU, strides 2-16, VGG-16 block widths) whose features are added to the colour features after each of
  the four levels (step-by-step fusion, FuseNet-style, as the RGB-D paper fuses), through 1x1 projections
  initialised to zero (step 0 = the colour-only network); then the paper's multi-scale feature fusion module on
  level 4 and a 1x1 classifier.  Depth encoding: one channel of metric depth normalised to (d - 2.5 m) / 1.5 m,
  invalid (0) pixels set to 0 after normalising (:func:`normalised_depth`); HHA is not used.  ``use_depth=False``
  is its colour-only twin.
"""

from __future__ import annotations

import torch
from torch import nn

from semmap.perception.espnetv2 import EESP, EESPNetEncoder, espnetv2_channels
from semmap.perception.networks.base import SegmentationNet
from semmap.perception.networks.cbam import CBAM
from semmap.perception.networks.layers import ConvBNReLU, init_weights, resize, scaled
from semmap.perception.networks.pspnet import DROPOUT, pyramid_heads
from semmap.perception.networks.registry import ESPNET_BACKBONES
from semmap.perception.networks.rgbd_net import DEPTH_MEAN_M, DEPTH_STD_M, MultiScaleFusion

#: Channels of the depth branch's four stages (strides 2, 4, 8, 16) at width 1 (VGG-16's first four blocks, as
#: the paper's depth sub-branch; width 0.25 gives 16, 32, 64, 128).
DEPTH_CHANNELS = (64, 128, 256, 512)
#: Channels of each branch of the RGB-D head's multi-scale fusion module at width 1.
MSFF_CHANNELS = 256


def espnet_scale(backbone: str) -> float:
    """Width multiplier s of an ESPNetv2 backbone name; ValueError naming the choices otherwise."""
    if backbone not in ESPNET_BACKBONES:
        raise ValueError(f"ESPNetv2 backbone must be one of {sorted(ESPNET_BACKBONES)}, got {backbone!r}")
    return ESPNET_BACKBONES[backbone]


def normalised_depth(depth: torch.Tensor) -> torch.Tensor:
    """The depth encoding of the RGB-D networks: (d - 2.5 m) / 1.5 m where d > 0, else 0."""
    return torch.where(depth > 0, (depth - DEPTH_MEAN_M) / DEPTH_STD_M, torch.zeros_like(depth))


class GatedCBAM(nn.Module):
    """``y + g (CBAM(y) - y)`` with a learnt scalar g starting at 0: the identity at initialisation, the paper's
    CBAM at g = 1, so attention can be added to a pretrained encoder without changing what it computes."""

    def __init__(self, channels: int) -> None:
        super().__init__()
        self.cbam = CBAM(channels)
        self.gate = nn.Parameter(torch.zeros(1))

    def forward(self, y: torch.Tensor) -> torch.Tensor:
        """The features, moved towards their attention-reweighted version by the gate."""
        return y + self.gate * (self.cbam(y) - y)


def _eesp_with_attention(unit: EESP, x: torch.Tensor, attention: nn.Module) -> torch.Tensor:
    """A residual EESP unit with ``attention`` on its branch before the shortcut add (CBAM-PSPNet, Fig. 3)."""
    p = unit.proj_1x1(x)
    outs = [unit.spp_dw[0](p)]
    for branch in unit.spp_dw[1:]:
        outs.append(branch(p) + outs[-1])
    y = unit.conv_1x1_exp(unit.br_after_cat(torch.cat(outs, 1)))
    return unit.module_act(attention(y) + x)


class ESPNetBackbone(nn.Module):
    """The ESPNetv2 encoder (``self.encoder``: the pretrained layers, named as in the published state dicts under
    ``base_net.``), optionally with gated CBAMs, returning levels 1-4; ``inject`` adds a tensor to the output of
    each level before the next one runs (the RGB-D net's fusion)."""

    def __init__(self, s: float, *, attention: bool = False) -> None:
        super().__init__()
        self.encoder = EESPNetEncoder(espnetv2_channels(s))
        self.channels = espnetv2_channels(s)
        self.attention = None
        if attention:
            c2, c3, c4 = self.channels[1:]
            units = [c2, c3, *(c3 for _ in self.encoder.level3), c4, *(c4 for _ in self.encoder.level4)]
            self.attention = nn.ModuleList(GatedCBAM(c) for c in units)

    def _unit(self, unit: EESP, x: torch.Tensor, i: int) -> torch.Tensor:
        return unit(x) if self.attention is None else _eesp_with_attention(unit, x, self.attention[i])

    def _down(self, x: torch.Tensor, i: int) -> torch.Tensor:
        return x if self.attention is None else self.attention[i](x)

    def forward(self, x: torch.Tensor, inject: list[torch.Tensor] | None = None
                ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """Features at strides 2, 4, 8 and 16."""
        e, n3 = self.encoder, len(self.encoder.level3)

        def add(level: int, y: torch.Tensor) -> torch.Tensor:
            return y if inject is None else y + inject[level]

        l1 = add(0, e.level1(x))
        l2 = add(1, self._down(e.level2_0(l1, x), 0))
        l3 = self._down(e.level3_0(l2, x), 1)
        for i, unit in enumerate(e.level3):
            l3 = self._unit(unit, l3, 2 + i)
        l3 = add(2, l3)
        l4 = self._down(e.level4_0(l3, x), 2 + n3)
        for i, unit in enumerate(e.level4):
            l4 = self._unit(unit, l4, 3 + n3 + i)
        return l1, l2, l3, add(3, l4)


class ESPNetFCN(SegmentationNet):
    """FCN-8s-style skip head on the ESPNetv2 encoder: scores of levels 2-4 fused coarse to fine (stride 4)."""

    #: where the pretrained encoder's tensors go (``base_net.`` of the published files)
    encoder_prefix = "backbone.encoder."

    def __init__(self, num_classes: int, *, backbone: str = "espnetv2-s1", full_resolution: bool = False) -> None:
        super().__init__(num_classes, full_resolution=full_resolution)
        self.backbone = ESPNetBackbone(espnet_scale(backbone))
        c4, c8, c16 = self.backbone.channels[1:]
        self.score4 = nn.Conv2d(c4, num_classes, 1)
        self.score8 = nn.Conv2d(c8, num_classes, 1)
        self.score16 = nn.Conv2d(c16, num_classes, 1)
        init_weights(self)

    def heads(self, image: torch.Tensor, depth: torch.Tensor | None) -> tuple[torch.Tensor, None]:
        _, f4, f8, f16 = self.backbone(image)
        s8 = self.score8(f8) + resize(self.score16(f16), f8.shape[-2:])
        return self.score4(f4) + resize(s8, f4.shape[-2:]), None


class ESPNetPSP(SegmentationNet):
    """PSPNet's pyramid pooling head on the ESPNetv2 encoder (stride 16), auxiliary head on level 3;
    ``attention``: CBAM-PSPNet (gated CBAMs in the encoder, identity at initialisation)."""

    encoder_prefix = "backbone.encoder."

    def __init__(self, num_classes: int, *, backbone: str = "espnetv2-s1", width: float = 0.25,
                 attention: bool = False, full_resolution: bool = False) -> None:
        super().__init__(num_classes, full_resolution=full_resolution)
        self.backbone = ESPNetBackbone(espnet_scale(backbone), attention=attention)
        self.ppm, self.head, self.aux = pyramid_heads(*self.backbone.channels[2:], num_classes, width)
        init_weights(self)
        if attention:  # init_weights touched the CBAM convolutions only; the gates must stay closed
            for m in self.backbone.attention:
                nn.init.zeros_(m.gate)

    def heads(self, image: torch.Tensor, depth: torch.Tensor | None) -> tuple[torch.Tensor, torch.Tensor | None]:
        _, _, c3, c4 = self.backbone(image)
        return self.head(self.ppm(c4)), (self.aux(c3) if self.training else None)


class DepthBranch(nn.Module):
    """The RGB-D net's depth encoder: four stages of a strided and a plain 3x3 conv + BN + ReLU (strides 2-16)."""

    def __init__(self, width: float) -> None:
        super().__init__()
        chans = [scaled(c, width) for c in DEPTH_CHANNELS]
        stages, cin = [], 1
        for c in chans:
            stages.append(nn.Sequential(ConvBNReLU(cin, c, 3, stride=2), ConvBNReLU(c, c, 3)))
            cin = c
        self.stages = nn.ModuleList(stages)
        self.channels = tuple(chans)

    def forward(self, d: torch.Tensor) -> list[torch.Tensor]:
        """Depth features at strides 2, 4, 8 and 16."""
        out = []
        for stage in self.stages:
            d = stage(d)
            out.append(d)
        return out


class ESPNetRGBD(SegmentationNet):
    """The RGB-D net on the ESPNetv2 colour encoder: depth branch fused after every level through zero-initialised
    1x1 projections, multi-scale fusion module on level 4; ``use_depth=False``: the colour-only twin."""

    encoder_prefix = "color.encoder."

    def __init__(self, num_classes: int, *, backbone: str = "espnetv2-s1", width: float = 0.25,
                 use_depth: bool = True, msff_dilation: int = 12, full_resolution: bool = False) -> None:
        super().__init__(num_classes, full_resolution=full_resolution)
        if msff_dilation < 1:
            raise ValueError(f"fusion-module dilation must be at least 1, got {msff_dilation}")
        self.uses_depth = use_depth
        self.color = ESPNetBackbone(espnet_scale(backbone))
        c4 = self.color.channels[3]
        if use_depth:
            self.depth = DepthBranch(width)
            self.fuse = nn.ModuleList(nn.Conv2d(cd, cc, 1, bias=False)
                                      for cd, cc in zip(self.depth.channels, self.color.channels, strict=True))
        self.fusion = MultiScaleFusion(c4, scaled(MSFF_CHANNELS, width), msff_dilation)
        self.classifier = nn.Sequential(nn.Dropout2d(DROPOUT), nn.Conv2d(self.fusion.out_channels, num_classes, 1))
        init_weights(self)
        if use_depth:  # step 0 computes the colour-only function: depth enters as training opens the projections
            for conv in self.fuse:
                nn.init.zeros_(conv.weight)

    def heads(self, image: torch.Tensor, depth: torch.Tensor | None) -> tuple[torch.Tensor, None]:
        self._check_depth(depth)
        inject = None
        if self.uses_depth:
            inject = [proj(f) for proj, f in zip(self.fuse, self.depth(normalised_depth(depth)), strict=True)]
        *_, l4 = self.color(image, inject)
        return self.classifier(self.fusion(l4)), None
