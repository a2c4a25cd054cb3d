"""CBAM-PSPNet (semantic-octomap-cbam-pspnet, Sec. 3.2, Fig. 3): PSPNet whose backbone carries a CBAM (channel then
spatial attention, eqs. 1-2) on the residual branch of every block, before the shortcut add, leaving the ResNet's
structure (strides, dilations, widths) unchanged."""

from __future__ import annotations

from semmap.perception.networks.cbam import CBAM
from semmap.perception.networks.pspnet import PSPNet


class CBAMPSPNet(PSPNet):
    """:class:`PSPNet` with :class:`CBAM` after every residual block's branch."""

    def __init__(self, num_classes: int, *, depth: int = 50, width: float = 1.0, output_stride: int = 8,
                 full_resolution: bool = False) -> None:
        super().__init__(num_classes, depth=depth, width=width, output_stride=output_stride, attention=CBAM,
                         full_resolution=full_resolution)
