"""Training-time augmentation on batches of tensors, driven by one seeded ``torch.Generator``: horizontal flips,
random scale (zoom in or out, then crop or pad back to the training size) and colour jitter (brightness,
contrast, saturation).  Padding gets label 0 (ignored) and depth 0 (invalid).

:meth:`Augmentation.sensor` adds what a real camera does to an image and a simulator does not, so a network trained
on simulated rooms meets fewer surprises on real frames: a wider zoom (another field of view and distance), white
balance, exposure (gamma), blur, sensor noise; on depth, noise growing with the square of the distance, a slight
scale error and holes (blobs of no return)."""

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
    white_balance: float = 0.0  #: per-channel gain within 1 +- this
    gamma: float = 0.0  #: exposure curve x ** g, g within 1 +- this
    blur: float = 0.0  #: Gaussian blur of sigma up to this (pixels)
    noise: float = 0.0  #: per-pixel Gaussian noise of std up to this (of the 0-1 range)
    depth_noise: float = 0.0  #: depth noise std at 1 m (metres), growing with the square of the depth
    depth_scale: float = 0.0  #: depth scaled by 1 +- this (a sensor's calibration)
    depth_holes: float = 0.0  #: up to this share of the depth image dropped in blobs

    @classmethod
    def sensor(cls) -> Augmentation:
        """Ranges for real-sensor-like frames (``semmap train --sensor-augment``)."""
        return cls(scale=(0.6, 1.6), brightness=0.4, contrast=0.35, saturation=0.4, white_balance=0.15, gamma=0.35,
                   blur=1.5, noise=0.04, depth_noise=0.004, depth_scale=0.03, depth_holes=0.15)


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
        x = _camera(x, aug, gen)
        if d is not None:
            d = _depth_sensor(d, aug, gen)
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


def _camera(x: torch.Tensor, aug: Augmentation, gen: torch.Generator) -> torch.Tensor:
    """White balance, exposure (gamma), blur and noise of a real colour camera (each off at 0)."""
    if aug.white_balance > 0:
        gains = torch.tensor([_uniform(gen, 1 - aug.white_balance, 1 + aug.white_balance) for _ in range(3)])
        x = x * gains.view(1, 3, 1, 1)
    if aug.gamma > 0:
        x = x.clamp(0.0, 1.0) ** _uniform(gen, 1 - aug.gamma, 1 + aug.gamma)
    if aug.blur > 0:
        sigma = _uniform(gen, 0.0, aug.blur)
        if sigma > 0.3:
            r = max(1, round(2.5 * sigma))
            t = torch.arange(-r, r + 1, dtype=x.dtype)
            k = torch.exp(-0.5 * (t / sigma) ** 2)
            k = k / k.sum()
            c = x.shape[1]
            x = F.conv2d(F.pad(x, (r, r, 0, 0), mode="replicate"), k.view(1, 1, 1, -1).repeat(c, 1, 1, 1), groups=c)
            x = F.conv2d(F.pad(x, (0, 0, r, r), mode="replicate"), k.view(1, 1, -1, 1).repeat(c, 1, 1, 1), groups=c)
    if aug.noise > 0:
        x = x + _uniform(gen, 0.0, aug.noise) * torch.randn(x.shape, generator=gen, dtype=x.dtype)
    return x.clamp(0.0, 1.0)


def _depth_sensor(d: torch.Tensor, aug: Augmentation, gen: torch.Generator) -> torch.Tensor:
    """Depth noise growing with the square of the depth, a scale error and holes in blobs (each off at 0)."""
    valid = d > 0
    if aug.depth_scale > 0:
        d = d * _uniform(gen, 1 - aug.depth_scale, 1 + aug.depth_scale)
    if aug.depth_noise > 0:
        d = d + aug.depth_noise * d * d * torch.randn(d.shape, generator=gen, dtype=d.dtype)
    if aug.depth_holes > 0:
        h, w = d.shape[-2:]
        coarse = torch.rand((1, 1, max(1, h // 16), max(1, w // 16)), generator=gen)
        blobs = F.interpolate(coarse, size=(h, w), mode="bilinear", align_corners=False)
        valid = valid & (blobs >= _uniform(gen, 0.0, aug.depth_holes))
    return torch.where(valid, d.clamp(min=0.0), torch.zeros_like(d))
