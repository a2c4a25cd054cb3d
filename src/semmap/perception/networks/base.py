"""What every semmap segmentation network shares: logits over ``num_classes`` from a normalised RGB image (and
a depth image in metres, for networks with ``uses_depth``), at the network's output stride for inference (the
segmenter samples them at each image pixel) or at the input size for training, with an optional auxiliary output."""

from __future__ import annotations

import torch
from torch import nn

from semmap.perception.networks.layers import resize


class SegmentationNet(nn.Module):
    """Base of the networks: subclasses implement :meth:`heads`; ``forward`` is what inference and ONNX export
    trace, :meth:`forward_train` what the trainer calls."""

    #: whether :meth:`forward` takes a depth image (N, 1, H, W) in metres after the RGB image
    uses_depth: bool = False
    #: the segmenter samples logits with the ``align_corners=False`` geometry used by :func:`layers.resize`
    logits_align_corners: bool = False

    def __init__(self, num_classes: int, *, full_resolution: bool = False) -> None:
        super().__init__()
        if num_classes < 2:
            raise ValueError(f"a segmentation network needs at least 2 classes, got {num_classes}")
        self.num_classes = num_classes
        #: True: :meth:`forward` upsamples logits to the input size (for users calling the module directly)
        self.full_resolution = full_resolution

    def heads(self, image: torch.Tensor, depth: torch.Tensor | None) -> tuple[torch.Tensor, torch.Tensor | None]:
        """(main logits, auxiliary logits or None), each at its own output stride."""
        raise NotImplementedError

    def forward(self, image: torch.Tensor, depth: torch.Tensor | None = None) -> torch.Tensor:
        """(N, K, h, w) logits: at the output stride, or at the input size with ``full_resolution``."""
        logits, _ = self.heads(image, depth)
        return resize(logits, image.shape[-2:]) if self.full_resolution else logits

    def forward_train(self, image: torch.Tensor, depth: torch.Tensor | None = None
                      ) -> tuple[torch.Tensor, torch.Tensor | None]:
        """(main logits, auxiliary logits or None), both upsampled to the input size."""
        logits, aux = self.heads(image, depth)
        size = image.shape[-2:]
        return resize(logits, size), (None if aux is None else resize(aux, size))

    def _check_depth(self, depth: torch.Tensor | None) -> None:
        if self.uses_depth and depth is None:
            raise ValueError(f"{type(self).__name__} needs a depth image")
