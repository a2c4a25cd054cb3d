"""Training-time augmentation on batches of tensors, driven by one seeded ``torch.Generator``: horizontal flips,
random scale (zoom in or out, then crop or pad back to the training size) and colour jitter (brightness,
contrast, saturation).  Padding gets label 0 (ignored) and depth 0 (invalid)."""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F  # noqa: N812  (the usual PyTorch alias)


@dataclass(frozen=True)
class Augmentation:
    """Ranges of the random changes; ``enabled=False`` passes batches through."""

    flip: bool = True
    scale: tuple[float, float] = (0.75, 1.25)
    brightness: float = 0.2
    contrast: float = 0.2
    saturation: float = 0.2
    enabled: bool = True


def _uniform(gen: torch.Generator, lo: float, hi: float) -> float:
    return lo + (hi - lo) * float(torch.rand((), generator=gen))


def augment(rgb: torch.Tensor, labels: torch.Tensor, depth: torch.Tensor | None, aug: Augmentation,
            gen: torch.Generator) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
    """Augment a batch: rgb (N, 3, H, W) float in [0, 1], labels (N, H, W) int64, depth (N, 1, H, W) metres."""
    if not aug.enabled:
        return rgb, labels, depth
    out_rgb, out_lab, out_d = [], [], []
    for i in range(rgb.shape[0]):
        x, y = rgb[i:i + 1], labels[i:i + 1, None].float()
        d = None if depth is None else depth[i:i + 1]
        if aug.flip and float(torch.rand((), generator=gen)) < 0.5:
            x, y = x.flip(-1), y.flip(-1)
            d = None if d is None else d.flip(-1)
        s = _uniform(gen, *aug.scale)
        if abs(s - 1.0) > 1e-3:
            x, y, d = _rescale(x, y, d, s, gen)
        x = _jitter(x, aug, gen)
        out_rgb.append(x)
        out_lab.append(y)
        out_d.append(d)
    rgb_out = torch.cat(out_rgb)
    lab_out = torch.cat(out_lab)[:, 0].round().long()
    return rgb_out, lab_out, None if depth is None else torch.cat(out_d)


def _rescale(x: torch.Tensor, y: torch.Tensor, d: torch.Tensor | None, s: float, gen: torch.Generator):
    """Zoom by ``s`` about a random point and crop / pad back to the original size."""
    h, w = x.shape[-2:]
    nh, nw = max(1, round(h * s)), max(1, round(w * s))
    x = F.interpolate(x, size=(nh, nw), mode="bilinear", align_corners=False)
    y = F.interpolate(y, size=(nh, nw), mode="nearest")
    d = None if d is None else F.interpolate(d, size=(nh, nw), mode="nearest")
    if s > 1.0:  # crop a random window
        top = int(torch.randint(0, nh - h + 1, (), generator=gen))
        left = int(torch.randint(0, nw - w + 1, (), generator=gen))
        sl = (..., slice(top, top + h), slice(left, left + w))
        return x[sl], y[sl], (None if d is None else d[sl])
    top = int(torch.randint(0, h - nh + 1, (), generator=gen))
    left = int(torch.randint(0, w - nw + 1, (), generator=gen))
    pad = (left, w - nw - left, top, h - nh - top)
    fill = x.mean()
    return (F.pad(x, pad, value=float(fill)), F.pad(y, pad, value=0.0),
            None if d is None else F.pad(d, pad, value=0.0))


def _jitter(x: torch.Tensor, aug: Augmentation, gen: torch.Generator) -> torch.Tensor:
    """Brightness (gain), contrast (about the mean grey) and saturation (about each pixel's grey)."""
    b = _uniform(gen, 1 - aug.brightness, 1 + aug.brightness)
    c = _uniform(gen, 1 - aug.contrast, 1 + aug.contrast)
    s = _uniform(gen, 1 - aug.saturation, 1 + aug.saturation)
    x = x * b
    grey = (0.299 * x[:, 0:1] + 0.587 * x[:, 1:2] + 0.114 * x[:, 2:3])
    x = (x - grey.mean()) * c + grey.mean()
    grey = (0.299 * x[:, 0:1] + 0.587 * x[:, 1:2] + 0.114 * x[:, 2:3])
    x = (x - grey) * s + grey
    return x.clamp(0.0, 1.0)
