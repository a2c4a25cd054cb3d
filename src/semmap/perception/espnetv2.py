"""ESPNetv2 semantic segmentation network (Mehta et al., CVPR 2019), written to load the EdgeNets PASCAL VOC weights.

The layout (module names, channel counts, groups) follows the tensor names and shapes of the published state dicts,
so ``load_state_dict(strict=True)`` works on ``espnetv2_s_{1.0,2.0}_pascal_384x384.pth``.

Encoder (``base_net``), for an input of size H x W:

* ``level1``: 3x3 stride-2 conv + BN + PReLU, 32 channels at H/2.
* ``level2_0``, ``level3_0``, ``level4_0``: strided EESP downsamplers (H/4, H/8, H/16). Each concatenates an
  average-pooled copy of its input with a stride-2 EESP unit's output, adds the *input reinforcement* (the RGB
  image average-pooled to the same size and projected by a 3x3 CBR + 1x1 CB) and applies a PReLU.
* ``level3`` (3 units) and ``level4`` (7 units): residual EESP units.

EESP unit: grouped (K=4) 1x1 projection to ``n = out/4`` channels, four depthwise 3x3 branches, hierarchical
feature fusion (branch i output plus the running sum of branches < i), concat, BN + PReLU, grouped (K=4) 1x1
expansion + BN, residual add (non-strided units only), PReLU. The branch dilations come from a per-level limit on
the effective receptive field (13, 11, 9, 9, 7 for level2_0, level3_0, level3, level4_0, level4): branch i would
have an effective kernel of 3 + 2i, any kernel over the limit falls back to 3, sorted ascending, dilation
(kernel - 1) / 2. So every unit uses dilations 1, 2, 3, 4 except the level-4 residual units, which use 1, 1, 2, 3.
(Checked against the weights: with these rates the pre-BN statistics of every branch on real images match the
stored BN running statistics best; dilation 2 in the second branch of a level-4 unit fits clearly worse.)

Decoder: bottom-up. The level-4 features go through an efficient pyramid pooling block (``bu_dec_l1``: project to
10 channels, 5 depthwise 3x3 convs at spatial scales 2, 1.5, 1, 0.5, 0.1, concat, BN+PReLU, channel shuffle, grouped
3x3 CBR, 1x1 conv), are upsampled x2 and added to the level-3 features squeezed by ``merge_enc_dec_l2`` (grouped 3x3
CBR gated by a global-pooled sigmoid channel weight), BN+PReLU (``bu_br_l2``); the same again for level 2 and
level 1; ``bu_dec_l4`` gives the 21 class logits at H/2, bilinearly upsampled to H x W.
"""

from __future__ import annotations

import functools
import math
import re
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F  # noqa: N812  (the usual PyTorch alias)
from torch import nn

from semmap.errors import FormatError
from semmap.files.safe import path_kind

#: Branches per EESP unit (the "K" of the paper); also the group count of its 1x1 convolutions.
EESP_BRANCHES = 4
#: Effective receptive-field limits of the EESP branches: level2_0, level3_0, level3 units, level4_0, level4 units.
RECEPTIVE_FIELD_LIMITS = (13, 11, 9, 9, 7)
#: Residual EESP units after each strided one, for levels 3 and 4.
LEVEL_REPEATS = (3, 7)
#: Spatial scales of the depthwise convolutions in each decoder pyramid-pooling block.
PYRAMID_SCALES = (2.0, 1.5, 1.0, 0.5, 0.1)
#: Smallest side (pixels) a pyramid branch is resized to, so its 3x3 convolution sees some context.
PYRAMID_MIN_SIDE = 5
#: Decoder base width (PASCAL VOC models): the first three pyramid blocks output 4x, 3x and 2x this many channels,
#: and every pyramid block projects to min(classes // 2, base) channels.
DECODER_BASE = 16
#: PASCAL VOC class count (background + 20 objects).
NUM_CLASSES = 21
#: Input normalisation the weights were trained with (RGB in [0, 1]).
IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)
#: Square training resolution of the published weights.
TRAIN_SIZE = 384


def espnetv2_channels(s: float) -> tuple[int, int, int, int]:
    """Output channels of encoder levels 1-4 for width multiplier ``s``: base = 32 s rounded up to a multiple of K,
    level 1 = min(32, base), level i = base * 2^(i-1) (s=1: 32, 64, 128, 256; s=2: 32, 128, 256, 512)."""
    if s <= 0:
        raise ValueError(f"width multiplier must be positive, got {s}")
    base = math.ceil(int(32 * s) / EESP_BRANCHES) * EESP_BRANCHES
    return min(32, base), 2 * base, 4 * base, 8 * base


def eesp_dilations(receptive_limit: int, k: int = EESP_BRANCHES) -> tuple[int, ...]:
    """Dilations of an EESP unit's K branches: kernels 3, 5, 7, ... capped (back to 3) at the limit, sorted."""
    kernels = sorted(3 + 2 * i if 3 + 2 * i <= receptive_limit else 3 for i in range(k))
    return tuple((kk - 1) // 2 for kk in kernels)


# --------------------------------------------------------------------------------------------------
# Building blocks of the encoder (module attribute names match the published state dicts)
# --------------------------------------------------------------------------------------------------
class ConvBNAct(nn.Module):
    """Convolution + BatchNorm (+ PReLU): the basic CBR / CB unit of the encoder."""

    def __init__(self, cin: int, cout: int, k: int, stride: int = 1, groups: int = 1, act: bool = True) -> None:
        super().__init__()
        self.conv = nn.Conv2d(cin, cout, k, stride, padding=k // 2, groups=groups, bias=False)
        self.bn = nn.BatchNorm2d(cout)
        self.act = nn.PReLU(cout) if act else None

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Apply conv, BN and the optional PReLU."""
        x = self.bn(self.conv(x))
        return self.act(x) if self.act is not None else x


class DilatedDW(nn.Module):
    """Depthwise dilated 3x3 convolution (no BN): one spatial branch of an EESP unit."""

    def __init__(self, channels: int, dilation: int, stride: int) -> None:
        super().__init__()
        self.conv = nn.Conv2d(channels, channels, 3, stride, padding=dilation, dilation=dilation,
                              groups=channels, bias=False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Apply the depthwise dilated convolution."""
        return self.conv(x)


class BNAct(nn.Module):
    """BatchNorm + PReLU, applied to the concatenated EESP branches."""

    def __init__(self, channels: int) -> None:
        super().__init__()
        self.bn = nn.BatchNorm2d(channels)
        self.act = nn.PReLU(channels)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Normalise then activate."""
        return self.act(self.bn(x))


class EESP(nn.Module):
    """EESP unit: grouped 1x1 reduce, K depthwise dilated branches with hierarchical fusion, grouped 1x1 expand."""

    def __init__(self, cin: int, cout: int, stride: int = 1, dilations: tuple[int, ...] = (1, 2, 3, 4)) -> None:
        super().__init__()
        k = len(dilations)
        if cout % k or cin % k:
            raise ValueError(f"EESP channels {cin}->{cout} must be divisible by the branch count {k}")
        n = cout // k
        self.stride = stride
        self.proj_1x1 = ConvBNAct(cin, n, 1, groups=k)
        self.spp_dw = nn.ModuleList(DilatedDW(n, d, stride) for d in dilations)
        self.conv_1x1_exp = ConvBNAct(cout, cout, 1, groups=k, act=False)
        self.br_after_cat = BNAct(cout)
        self.module_act = nn.PReLU(cout)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Reduce, transform in K dilated branches fused hierarchically, merge; residual + PReLU when stride 1."""
        p = self.proj_1x1(x)
        outs = [self.spp_dw[0](p)]
        for branch in self.spp_dw[1:]:
            outs.append(branch(p) + outs[-1])  # hierarchical feature fusion removes gridding artefacts
        y = self.conv_1x1_exp(self.br_after_cat(torch.cat(outs, 1)))
        if self.stride == 2:
            return y  # the downsampler adds its own shortcut and activation
        return self.module_act(y + x)


class DownSampler(nn.Module):
    """Strided EESP level entry: [avg-pooled input, strided EESP] concat, plus the reinforced RGB input, PReLU."""

    def __init__(self, cin: int, cout: int, receptive_limit: int) -> None:
        super().__init__()
        self.eesp = EESP(cin, cout - cin, stride=2, dilations=eesp_dilations(receptive_limit))
        self.avg = nn.AvgPool2d(3, stride=2, padding=1)
        self.inp_reinf = nn.Sequential(ConvBNAct(3, 3, 3), ConvBNAct(3, cout, 1, act=False))
        self.act = nn.PReLU(cout)

    def forward(self, x: torch.Tensor, image: torch.Tensor) -> torch.Tensor:
        """Halve the resolution of ``x`` and re-inject the (downsampled) input ``image``."""
        y = torch.cat([self.avg(x), self.eesp(x)], 1)
        while image.shape[-2:] != y.shape[-2:]:
            if image.shape[-1] < y.shape[-1] or image.shape[-2] < y.shape[-2]:
                raise ValueError(f"cannot reinforce features of size {tuple(y.shape[-2:])} from image "
                                 f"{tuple(image.shape[-2:])}")
            image = F.avg_pool2d(image, 3, stride=2, padding=1)
        return self.act(y + self.inp_reinf(image))


class EESPNetEncoder(nn.Module):
    """ESPNetv2 backbone up to level 4 (H/16); returns the features of levels 1-4."""

    def __init__(self, channels: tuple[int, int, int, int]) -> None:
        super().__init__()
        c1, c2, c3, c4 = channels
        r2, r3_0, r3, r4_0, r4 = RECEPTIVE_FIELD_LIMITS
        self.level1 = ConvBNAct(3, c1, 3, stride=2)
        self.level2_0 = DownSampler(c1, c2, r2)
        self.level3_0 = DownSampler(c2, c3, r3_0)
        self.level3 = nn.ModuleList(EESP(c3, c3, dilations=eesp_dilations(r3)) for _ in range(LEVEL_REPEATS[0]))
        self.level4_0 = DownSampler(c3, c4, r4_0)
        self.level4 = nn.ModuleList(EESP(c4, c4, dilations=eesp_dilations(r4)) for _ in range(LEVEL_REPEATS[1]))

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """Features at H/2, H/4, H/8 and H/16."""
        l1 = self.level1(x)
        l2 = self.level2_0(l1, x)
        l3 = self.level3_0(l2, x)
        for unit in self.level3:
            l3 = unit(l3)
        l4 = self.level4_0(l3, x)
        for unit in self.level4:
            l4 = unit(l4)
        return l1, l2, l3, l4


# --------------------------------------------------------------------------------------------------
# Decoder blocks (attribute names match the published state dicts)
# --------------------------------------------------------------------------------------------------
class CBR(nn.Module):
    """Conv + BN + PReLU held in a ``cbr`` Sequential, as the decoder's weights name it."""

    def __init__(self, cin: int, cout: int, k: int, groups: int = 1) -> None:
        super().__init__()
        self.cbr = nn.Sequential(nn.Conv2d(cin, cout, k, padding=k // 2, groups=groups, bias=False),
                                 nn.BatchNorm2d(cout), nn.PReLU(cout))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Apply conv, BN, PReLU."""
        return self.cbr(x)


class BR(nn.Module):
    """BN + PReLU held in a ``br`` Sequential, as the decoder's weights name it."""

    def __init__(self, channels: int) -> None:
        super().__init__()
        self.br = nn.Sequential(nn.BatchNorm2d(channels), nn.PReLU(channels))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Normalise then activate."""
        return self.br(x)


class ChannelShuffle(nn.Module):
    """Interleave channels of ``groups`` equal groups so the next grouped conv mixes all of them."""

    def __init__(self, groups: int) -> None:
        super().__init__()
        self.groups = groups

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """(N, g*c, H, W) -> (N, c*g, H, W) with channel j*c+i moved to i*g+j."""
        n, c, h, w = x.shape
        return x.view(n, self.groups, c // self.groups, h, w).transpose(1, 2).reshape(n, c, h, w)


class PyramidPool(nn.Module):
    """Efficient pyramid pooling: depthwise 3x3 convs on a projected map resampled to several scales, then merged."""

    def __init__(self, cin: int, proj: int, cout: int, scales: tuple[float, ...] = PYRAMID_SCALES,
                 last_br: bool = True) -> None:
        super().__init__()
        self.scales = scales
        self.projection_layer = CBR(cin, proj, 1)
        self.stages = nn.ModuleList(nn.Conv2d(proj, proj, 3, padding=1, groups=proj, bias=False) for _ in scales)
        k = len(scales)
        self.merge_layer = nn.Sequential(BR(k * proj), ChannelShuffle(k), CBR(k * proj, proj, 3, groups=proj),
                                         nn.Conv2d(proj, cout, 1, bias=not last_br))
        self.br = BR(cout) if last_br else None

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Project, run each scale's depthwise conv at its own resolution, resample back, concat, merge."""
        x = self.projection_layer(x)
        h, w = int(x.shape[-2]), int(x.shape[-1])  # plain ints: ONNX export traces one input size
        outs = []
        for scale, stage in zip(self.scales, self.stages, strict=True):
            hs = max(PYRAMID_MIN_SIDE, math.ceil(h * scale))
            ws = max(PYRAMID_MIN_SIDE, math.ceil(w * scale))
            if (hs, ws) == (h, w):
                outs.append(stage(x))
            elif scale < 1.0:
                y = stage(adaptive_avg_pool(x, (hs, ws)))
                outs.append(F.interpolate(y, (h, w), mode="bilinear", align_corners=True))
            else:
                y = stage(F.interpolate(x, (hs, ws), mode="bilinear", align_corners=True))
                outs.append(adaptive_avg_pool(y, (h, w)))
        y = self.merge_layer(torch.cat(outs, 1))
        return self.br(y) if self.br is not None else y


class GatedProjection(nn.Module):
    """Encoder-to-decoder skip: grouped 3x3 CBR to the decoder width, scaled by a global-context sigmoid gate."""

    def __init__(self, cin: int, cout: int) -> None:
        super().__init__()
        self.wt_layer = nn.Sequential(nn.AdaptiveAvgPool2d(1), nn.Conv2d(cin, cout, 1, bias=False), nn.Sigmoid())
        self.expansion_layer = CBR(cin, cout, 3, groups=math.gcd(cin, cout))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Project ``x`` and reweight its channels from its global average."""
        return self.expansion_layer(x) * self.wt_layer(x)


@functools.lru_cache(maxsize=64)
def _pool_matrix_np(n_in: int, n_out: int) -> np.ndarray:
    """(n_out, n_in) float32 averaging weights of adaptive average pooling along one axis (bin i covers
    floor(i * n_in / n_out) .. ceil((i + 1) * n_in / n_out))."""
    m = np.zeros((n_out, n_in), np.float32)
    for i in range(n_out):
        lo, hi = (i * n_in) // n_out, -((-(i + 1) * n_in) // n_out)
        m[i, lo:hi] = 1.0 / (hi - lo)
    m.setflags(write=False)
    return m


def _pool_matrix(n_in: int, n_out: int) -> torch.Tensor:
    """The pooling weights as a tensor built outside autograd and tracing: the ONNX exporter sees one constant,
    where filling a tensor row by row in ``forward`` traced every row as a scatter (72k graph nodes, 30 s of CPU
    to open each ONNX Runtime session)."""
    return torch.from_numpy(_pool_matrix_np(n_in, n_out).copy())


def adaptive_avg_pool(x: torch.Tensor, size: tuple[int, int]) -> torch.Tensor:
    """``F.adaptive_avg_pool2d`` as two matrix products: the same numbers, and exportable to ONNX for any sizes
    (the exporter refuses adaptive pooling whose output size does not divide the input size)."""
    h, w = int(x.shape[-2]), int(x.shape[-1])
    rows, cols = _pool_matrix(h, size[0]).to(x.dtype), _pool_matrix(w, size[1]).to(x.dtype)
    return torch.matmul(torch.matmul(rows, x), cols.T)


def _bn_prelu(channels: int) -> nn.Sequential:
    """BN + PReLU as a bare Sequential (the ``bu_br_l*`` modules)."""
    return nn.Sequential(nn.BatchNorm2d(channels), nn.PReLU(channels))


class ESPNetv2Seg(nn.Module):
    """ESPNetv2 segmentation network: (N, 3, H, W) ImageNet-normalised RGB -> (N, classes, H, W) logits.

    With ``full_resolution=False`` the last bilinear upsampling is left out and the logits come at half the input
    resolution; :class:`~semmap.perception.network.NetworkSegmenter` then samples them straight to the image
    size, which is cheaper than upsampling twice.  Either way the logit grid spans the input corner to corner.
    """

    #: the logit grid's first and last samples sit on the input's first and last pixels
    logits_align_corners = True

    def __init__(self, s: float = 2.0, num_classes: int = NUM_CLASSES,
                 channels: tuple[int, int, int, int] | None = None, full_resolution: bool = True) -> None:
        super().__init__()
        self.s = s
        self.full_resolution = full_resolution
        self.num_classes = num_classes
        self.channels = tuple(channels) if channels is not None else espnetv2_channels(s)
        c1, c2, c3, c4 = self.channels
        d1, d2, d3 = 4 * DECODER_BASE, 3 * DECODER_BASE, 2 * DECODER_BASE
        proj = min(num_classes // 2, DECODER_BASE)
        self.base_net = EESPNetEncoder(self.channels)  # type: ignore[arg-type]
        self.bu_dec_l1 = PyramidPool(c4, proj, d1)
        self.bu_dec_l2 = PyramidPool(d1, proj, d2)
        self.bu_dec_l3 = PyramidPool(d2, proj, d3)
        self.bu_dec_l4 = PyramidPool(d3, proj, num_classes, last_br=False)
        self.merge_enc_dec_l2 = GatedProjection(c3, d1)
        self.merge_enc_dec_l3 = GatedProjection(c2, d2)
        self.merge_enc_dec_l4 = GatedProjection(c1, d3)
        self.bu_br_l2 = _bn_prelu(d1)
        self.bu_br_l3 = _bn_prelu(d2)
        self.bu_br_l4 = _bn_prelu(d3)

    @staticmethod
    def _up(x: torch.Tensor, like: torch.Tensor) -> torch.Tensor:
        """Bilinearly resize ``x`` to the spatial size of ``like``."""
        return F.interpolate(x, like.shape[-2:], mode="bilinear", align_corners=True)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """Class logits at the input resolution."""
        l1, l2, l3, l4 = self.base_net(x)
        y = self.bu_dec_l1(l4)
        y = self.bu_br_l2(self._up(y, l3) + self.merge_enc_dec_l2(l3))
        y = self.bu_dec_l2(y)
        y = self.bu_br_l3(self._up(y, l2) + self.merge_enc_dec_l3(l2))
        y = self.bu_dec_l3(y)
        y = self.bu_br_l4(self._up(y, l1) + self.merge_enc_dec_l4(l1))
        y = self.bu_dec_l4(y)
        if not self.full_resolution:
            return y
        return F.interpolate(y, x.shape[-2:], mode="bilinear", align_corners=True)


# --------------------------------------------------------------------------------------------------
# Loading
# --------------------------------------------------------------------------------------------------
_S_IN_NAME = re.compile(r"_s_(\d+(?:\.\d+)?)")


def _channels_from_state_dict(sd: Mapping[str, torch.Tensor]) -> tuple[int, int, int, int] | None:
    """Encoder level widths read off the PReLU weights of levels 1-4, or None when those keys are absent."""
    keys = ("base_net.level1.act.weight", "base_net.level2_0.act.weight",
            "base_net.level3_0.act.weight", "base_net.level4_0.act.weight")
    try:
        return tuple(int(sd[k].numel()) for k in keys)  # type: ignore[return-value]
    except (KeyError, AttributeError):
        return None


def infer_width_multiplier(sd: Mapping[str, torch.Tensor], path: str | Path = "") -> float:
    """Width multiplier s: level-2 width / 64 from the state dict, else the ``_s_X.Y`` in the file name."""
    channels = _channels_from_state_dict(sd)
    if channels is not None:
        return channels[1] / 64.0
    m = _S_IN_NAME.search(Path(path).name)
    if m:
        return float(m.group(1))
    raise FormatError(f"{path}: cannot tell the ESPNetv2 width multiplier (no base_net.level2_0.act.weight "
                      f"and no '_s_X.Y' in the file name)")


def _few(names: list[str], n: int = 5) -> str:
    """The first ``n`` names, comma-separated, with a count of the rest."""
    more = f" (+{len(names) - n} more)" if len(names) > n else ""
    return ", ".join(names[:n]) + more


def load_espnetv2(weights_path: str | Path, num_classes: int | None = None,
                  full_resolution: bool = True) -> ESPNetv2Seg:
    """Build ESPNetv2 for a state-dict file, load it strictly and return it in eval mode on the CPU
    (``full_resolution=False``: logits at half the input resolution, see :class:`ESPNetv2Seg`)."""
    path = Path(weights_path)
    if not path.is_file():
        raise FormatError(f"{path}: ESPNetv2 weights file not found" if not path.exists()
                          else f"{path}: {path_kind(path)}, expected an ESPNetv2 weights file (.pt)")
    from semmap.perception.networks.registry import check_finite_tensors, read_torch_file

    sd = read_torch_file(path, "PyTorch weights file")
    if isinstance(sd, Mapping) and "state_dict" in sd and isinstance(sd["state_dict"], Mapping):
        sd = sd["state_dict"]
    if not isinstance(sd, Mapping) or not sd or not all(isinstance(v, torch.Tensor) for v in sd.values()):
        raise FormatError(f"{path}: expected a state dict of tensors, got {type(sd).__name__}")
    sd = {k.removeprefix("module."): v for k, v in sd.items()}
    check_finite_tensors(sd, path)
    s = infer_width_multiplier(sd, path)
    if num_classes is None:
        head = sd.get("bu_dec_l4.merge_layer.3.bias")
        num_classes = int(head.numel()) if head is not None else NUM_CLASSES
    try:
        model = ESPNetv2Seg(s, num_classes, channels=_channels_from_state_dict(sd), full_resolution=full_resolution)
    except ValueError as exc:
        raise FormatError(f"{path}: state dict does not describe a buildable ESPNetv2 ({exc})") from exc
    expected = model.state_dict()
    missing = [k for k in expected if k not in sd]
    unexpected = [k for k in sd if k not in expected]
    if missing or unexpected:
        parts = []
        if missing:
            parts.append(f"{len(missing)} missing keys: {_few(missing)}")
        if unexpected:
            parts.append(f"{len(unexpected)} unexpected keys: {_few(unexpected)}")
        raise FormatError(f"{path}: not an ESPNetv2 (s={s:g}) segmentation state dict; " + "; ".join(parts))
    bad = [f"{k} {tuple(sd[k].shape)} != {tuple(v.shape)}" for k, v in expected.items() if sd[k].shape != v.shape]
    if bad:
        raise FormatError(f"{path}: {len(bad)} tensor shapes do not match ESPNetv2 s={s:g}: {_few(bad, 3)}")
    model.load_state_dict(sd, strict=True)
    return model.eval()


def save_espnetv2(path: str | Path, model: ESPNetv2Seg, meta: dict | None = None) -> Path:
    """Write ``model``'s state dict as :func:`load_espnetv2` reads it (``{"state_dict": ..., "meta": ...}``, the
    metadata plain data: a calibration temperature, how the weights were made), atomically."""
    import io

    from semmap.files.atomic import write_bytes_atomic

    buf = io.BytesIO()
    torch.save({"state_dict": {k: v.detach().cpu() for k, v in model.state_dict().items()}, "meta": meta or {}}, buf)
    return write_bytes_atomic(path, buf.getvalue())


def espnetv2_meta(path: str | Path) -> dict:
    """The metadata :func:`save_espnetv2` stored with an ESPNetv2 weights file ({} for the authors' files)."""
    from semmap.perception.networks.registry import read_torch_file

    blob = read_torch_file(path, "PyTorch weights file")
    meta = blob.get("meta") if isinstance(blob, Mapping) else None
    return dict(meta) if isinstance(meta, Mapping) else {}
