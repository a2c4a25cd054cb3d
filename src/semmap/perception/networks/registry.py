"""Networks by name, and their weight files: one ``.pt`` holding the architecture (:class:`NetworkSpec`), the
label set, the training input size and the state dict (float16 on disk, float32 in memory).

PyTorch is imported only when a network is built or a weight file read, so the names are cheap to list."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path
from typing import TYPE_CHECKING

from semmap.errors import ConfigError, FormatError
from semmap.files.safe import path_kind
from semmap.registry import Registry
from semmap.types import LabelSet

if TYPE_CHECKING:
    import torch

    from semmap.perception.networks.base import SegmentationNet


@dataclass(frozen=True)
class NetworkEntry:
    """A network by name: its builder ``(spec, full_resolution) -> network``, one line of help, its inputs."""

    name: str
    factory: Callable[[NetworkSpec, bool], SegmentationNet]
    help: str
    uses_depth: bool = False  #: takes the depth image as a fourth channel
    backbone: str | None = None  #: default backbone (None: a ResNet of ``spec.depth``); an ESPNetv2 one replaces it
    chooses_backbone: bool = False  #: ``spec.backbone`` picks ResNet or VGG-16


#: ESPNetv2 encoders any network can be built on (``NetworkSpec.backbone``) -> width multiplier s.
ESPNET_BACKBONES: dict[str, float] = {"espnetv2-s1": 1.0, "espnetv2-s2": 2.0}
#: Every backbone a spec may name (``resnet`` for FCN/PSPNet/CBAM-PSPNet, ``vgg16`` for FCN and the RGB-D net).
BACKBONES = ("resnet", "vgg16", *ESPNET_BACKBONES)


def _fcn(spec: NetworkSpec, full_resolution: bool) -> SegmentationNet:
    if spec.backbone in ESPNET_BACKBONES:
        from semmap.perception.networks.espnet import ESPNetFCN

        return ESPNetFCN(spec.num_classes, backbone=spec.backbone, full_resolution=full_resolution)
    from semmap.perception.networks.fcn import FCN8s

    return FCN8s(spec.num_classes, backbone=spec.backbone, depth=spec.depth, width=spec.width,
                 full_resolution=full_resolution)


def _espnet_psp(spec: NetworkSpec, full_resolution: bool, attention: bool) -> SegmentationNet:
    from semmap.perception.networks.espnet import ESPNetPSP

    return ESPNetPSP(spec.num_classes, backbone=spec.backbone, width=spec.width, attention=attention,
                     full_resolution=full_resolution)


def _pspnet(spec: NetworkSpec, full_resolution: bool) -> SegmentationNet:
    if spec.backbone in ESPNET_BACKBONES:
        return _espnet_psp(spec, full_resolution, attention=False)
    from semmap.perception.networks.pspnet import PSPNet

    return PSPNet(spec.num_classes, depth=spec.depth, width=spec.width, full_resolution=full_resolution)


def _cbam_pspnet(spec: NetworkSpec, full_resolution: bool) -> SegmentationNet:
    if spec.backbone in ESPNET_BACKBONES:
        return _espnet_psp(spec, full_resolution, attention=True)
    from semmap.perception.networks.cbam_pspnet import CBAMPSPNet

    return CBAMPSPNet(spec.num_classes, depth=spec.depth, width=spec.width, full_resolution=full_resolution)


def _rgbd_net(use_depth: bool) -> Callable[[NetworkSpec, bool], SegmentationNet]:
    def build(spec: NetworkSpec, full_resolution: bool) -> SegmentationNet:
        if spec.backbone in ESPNET_BACKBONES:
            from semmap.perception.networks.espnet import ESPNetRGBD

            return ESPNetRGBD(spec.num_classes, backbone=spec.backbone, width=spec.width, use_depth=use_depth,
                              msff_dilation=spec.msff_dilation, full_resolution=full_resolution)
        from semmap.perception.networks.rgbd_net import RGBDNet

        return RGBDNet(spec.num_classes, width=spec.width, use_depth=use_depth, msff_dilation=spec.msff_dilation,
                       full_resolution=full_resolution)

    return build


#: The networks ``semmap train --model`` trains and ``semmap run --segmenter`` runs (with their weight files).
MODELS: Registry[NetworkEntry] = Registry("network", [
    NetworkEntry("fcn", _fcn, "FCN-8s over a ResNet (or VGG-16) backbone", chooses_backbone=True),
    NetworkEntry("pspnet", _pspnet, "PSPNet: dilated ResNet, pyramid pooling 1/2/3/6, auxiliary head"),
    NetworkEntry("cbam-pspnet", _cbam_pspnet, "CBAM-PSPNet: PSPNet with channel + spatial attention in every "
                 "residual block"),
    NetworkEntry("rgbd-net", _rgbd_net(True), "RGB-D two-branch VGG-16 with step-by-step fusion and multi-scale "
                 "fusion module (needs depth)", uses_depth=True, backbone="vgg16"),
    NetworkEntry("rgb-only", _rgbd_net(False), "the RGB-D network's colour-only twin", backbone="vgg16"),
], option="--model")
#: Marker and version of semmap's network weight files.
WEIGHTS_FORMAT = "semmap-network"
WEIGHTS_VERSION = 1


@dataclass(frozen=True)
class NetworkSpec:
    """Everything that fixes a network's architecture: ``model`` (a :data:`MODELS` name), classes, width
    multiplier, ResNet depth (FCN / PSPNet / CBAM-PSPNet), FCN backbone, RGB-D fusion-module dilation."""

    model: str
    num_classes: int
    width: float = 1.0
    depth: int = 50
    backbone: str = "resnet"
    msff_dilation: int = 12

    def __post_init__(self) -> None:
        if self.model not in MODELS:
            raise ConfigError(MODELS.unknown(self.model))
        if not (math.isfinite(self.width) and 0 < self.width <= 4):
            raise ConfigError(f"width multiplier must be in (0, 4], got {self.width}")
        if self.backbone not in BACKBONES:
            raise ConfigError(f"--backbone: unknown backbone {self.backbone!r}; choose from {', '.join(BACKBONES)}")

    @property
    def uses_depth(self) -> bool:
        return MODELS[self.model].uses_depth

    def describe(self) -> str:
        """Short name with the size, e.g. ``cbam-pspnet-r18-w0.25``."""
        entry = MODELS[self.model]
        if self.backbone in ESPNET_BACKBONES:
            return f"{self.model}-{self.backbone}-w{self.width:g}"
        if entry.backbone is not None:
            return f"{self.model}-{entry.backbone}-w{self.width:g}"
        bb = "vgg16" if entry.chooses_backbone and self.backbone == "vgg16" else f"r{self.depth}"
        return f"{self.model}-{bb}-w{self.width:g}"

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> NetworkSpec:
        known = {f.name for f in fields(cls)}
        return cls(**{k: v for k, v in d.items() if k in known})


def build_network(spec: NetworkSpec, *, full_resolution: bool = False) -> SegmentationNet:
    """A freshly initialised network for ``spec``."""
    try:
        return MODELS[spec.model].factory(spec, full_resolution)
    except ValueError as exc:
        raise ConfigError(f"cannot build {spec.describe()}: {exc}") from None


def count_parameters(model: torch.nn.Module) -> int:
    return sum(p.numel() for p in model.parameters())


@dataclass(frozen=True)
class NetworkWeights:
    """A loaded weight file: the network (eval mode, float32), its spec, label set, training input size
    (width, height) and the metadata stored with it (training command, data, metrics)."""

    model: SegmentationNet
    spec: NetworkSpec
    label_set: LabelSet
    input_size: tuple[int, int]
    meta: dict


def save_weights(path: str | Path, model: SegmentationNet, spec: NetworkSpec, label_set: LabelSet,
                 input_size: tuple[int, int], meta: dict | None = None) -> Path:
    """Write a weight file atomically (float16 tensors: half the size, no measurable accuracy change)."""
    from semmap.files.atomic import write_bytes_atomic

    state = {k: (v.detach().cpu().half() if v.is_floating_point() else v.detach().cpu())
             for k, v in model.state_dict().items()}
    blob = {"format": WEIGHTS_FORMAT, "version": WEIGHTS_VERSION, "spec": spec.to_dict(),
            "label_set": label_set.to_dict(), "input_size": list(input_size), "meta": meta or {},
            "state_dict": state}
    import io

    import torch

    buf = io.BytesIO()
    torch.save(blob, buf)
    return write_bytes_atomic(path, buf.getvalue())


def load_weights(path: str | Path, *, full_resolution: bool = False) -> NetworkWeights:
    """Read a weight file written by :func:`save_weights` (or a training checkpoint); FormatError naming the
    file when it is not one."""
    path = Path(path)
    if not path.is_file():
        raise FormatError(f"{path}: network weights file not found" if not path.exists()
                          else f"{path}: {path_kind(path)}, expected a network weights file (.pt)")
    blob = read_torch_file(path, "network weights file")
    if not isinstance(blob, dict) or blob.get("format") != WEIGHTS_FORMAT:
        raise FormatError(f"{path}: not a semmap network weights file (no '{WEIGHTS_FORMAT}' marker)")
    try:
        spec = NetworkSpec.from_dict(blob["spec"])
        label_set = LabelSet.from_dict(blob["label_set"])
        input_size = (int(blob["input_size"][0]), int(blob["input_size"][1]))
        state = blob["state_dict"]
    except (KeyError, TypeError, IndexError, ValueError, ConfigError) as exc:
        raise FormatError(f"{path}: malformed network weights file ({exc})") from None
    if spec.num_classes != len(label_set):
        raise FormatError(f"{path}: network predicts {spec.num_classes} classes but its label set has "
                          f"{len(label_set)}")
    check_finite_tensors(state, path)
    model = build_network(spec, full_resolution=full_resolution)
    expected = model.state_dict()
    bad = sorted(set(expected) ^ set(state))
    bad += [k for k in expected if k in state and tuple(state[k].shape) != tuple(expected[k].shape)]
    if bad:
        raise FormatError(f"{path}: state dict does not match {spec.describe()} ({len(bad)} tensors differ, "
                          f"e.g. {bad[0]})")
    model.load_state_dict({k: v.to(expected[k].dtype) for k, v in state.items()})
    return NetworkWeights(model.eval(), spec, label_set, input_size, dict(blob.get("meta") or {}))


def read_torch_file(path: str | Path, what: str) -> object:
    """``torch.load`` of a user's file with plain data and tensors only; FormatError in one line of semmap's own
    when it is not readable or holds other Python objects (torch's own message advises an unsafe reload)."""
    import pickle

    import torch

    try:
        return torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as exc:  # torch's text advises an unsafe reload: never shown
        if "Unsupported global" in str(exc) or "Unsupported class" in str(exc):  # an object besides plain data
            raise FormatError(f"{path}: refused: this {what} holds Python objects besides tensors and plain data, "
                              f"which could run code when loaded; semmap reads only plain weight files") from None
        raise FormatError(f"{path}: cannot read this {what} (not a PyTorch file, or a damaged one)") from None
    except Exception as exc:  # torch raises many types for a corrupt / non-torch file
        first = str(exc).strip().splitlines()[0][:160] if str(exc).strip() else ""
        raise FormatError(f"{path}: cannot read this {what} ({type(exc).__name__}: {first})") from None


def check_finite_tensors(state: object, path: str | Path) -> None:
    """FormatError naming the file and a tensor when a state dict holds NaN or infinite values."""
    import torch

    if not isinstance(state, dict):
        return
    for key, value in state.items():
        if isinstance(value, torch.Tensor) and value.is_floating_point() and not bool(torch.isfinite(value).all()):
            raise FormatError(f"{path}: weights hold NaN or infinite values (tensor {key}); the file is damaged "
                              f"or comes from a diverged training")


def with_classes(spec: NetworkSpec, num_classes: int) -> NetworkSpec:
    return replace(spec, num_classes=num_classes)
