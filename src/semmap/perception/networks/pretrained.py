"""Pretrained starts for ``semmap train --init``: copy the tensors of a pretrained encoder that match a freshly
built network (same name after renaming, same shape) and report what was loaded and what stays new.

* ``espnetv2-pascal-s1`` / ``-s2`` (``espnetv2-pascal`` = s2, the segmenter's default): the ESPNetv2 encoder
  trained on ImageNet then PASCAL VOC (``espnetv2_s_{1.0,2.0}_pascal_384x384.pth``, MIT licence) from
  ``$SEMMAP_PRETRAINED_DIR``, the shipped ``weights/espnetv2`` or ``../shared/weights/espnetv2``; its
  ``base_net.`` tensors go to the network's encoder, the PASCAL decoder is left out.
* ``torchvision:resnet18|34|50`` and ``torchvision:vgg16``: torchvision's ImageNet weights (downloaded, where
  the machine can) into the full-width (``--width 1``) ResNet or VGG-16 backbones.  VGG-16 has no BatchNorm:
  each conv's bias moves into the BN that follows it here, with unit scale and zero mean (the same function).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from semmap.errors import ConfigError, FormatError

if TYPE_CHECKING:
    import torch
    from torch import nn

#: --init names of the ESPNetv2 PASCAL encoders -> the backbone they need.
ESPNET_INITS = {"espnetv2-pascal": "espnetv2-s2", "espnetv2-pascal-s1": "espnetv2-s1",
                "espnetv2-pascal-s2": "espnetv2-s2"}
#: ESPNetv2 backbone -> its published weight file.
ESPNET_FILES = {"espnetv2-s1": "espnetv2_s_1.0_pascal_384x384.pth", "espnetv2-s2": "espnetv2_s_2.0_pascal_384x384.pth"}
#: Where the ESPNetv2 files lie beside the repository (``../shared/weights/espnetv2``).
ESPNET_SHARED_DIR = Path("shared/weights/espnetv2")
#: Environment variable naming the folder of the ESPNetv2 files.
PRETRAINED_ENV = "SEMMAP_PRETRAINED_DIR"
TORCHVISION = "torchvision:"
#: torchvision architectures --init takes -> (backbone, ResNet depth).
TORCHVISION_MODELS = {"resnet18": ("resnet", 18), "resnet34": ("resnet", 34), "resnet50": ("resnet", 50),
                      "vgg16": ("vgg16", 18)}
#: Prefixes of the pretrained file's encoder tensors.
ESPNET_ENCODER = "base_net."


@dataclass(frozen=True)
class InitPlan:
    """What an ``--init`` name fixes of the architecture: the backbone, and for torchvision the ResNet depth and
    full width (its weights fit only the full-size layers)."""

    name: str
    backbone: str
    depth: int | None = None
    width: float | None = None
    msff_dilation: int | None = None
    model: str | None = None  #: a semmap weight file fixes the network too

def init_choices() -> tuple[str, ...]:
    """Every name ``--init`` takes (besides a semmap weight file, ``NET.pt``: fine-tune it)."""
    return (*ESPNET_INITS, *(TORCHVISION + m for m in TORCHVISION_MODELS))


def is_weight_file(name: str) -> bool:
    """``--init`` names one of semmap's own weight files (a shipped network or a run's best.pt) to fine-tune."""
    return str(name).endswith(".pt")


def init_plan(name: str) -> InitPlan:
    """The plan of ``--init name``; ConfigError listing the choices for another name."""
    if name in ESPNET_INITS:
        return InitPlan(name, ESPNET_INITS[name])
    if is_weight_file(name):
        from semmap.perception.networks.registry import load_weights

        if not Path(name).is_file():
            raise ConfigError(f"--init {name}: no such weight file")
        spec = load_weights(Path(name)).spec
        return InitPlan(name, spec.backbone, spec.depth, spec.width, spec.msff_dilation, spec.model)
    arch = name.removeprefix(TORCHVISION)
    if name.startswith(TORCHVISION) and arch in TORCHVISION_MODELS:
        backbone, depth = TORCHVISION_MODELS[arch]
        return InitPlan(name, backbone, depth, 1.0)
    raise ConfigError(f"--init: unknown pretrained start {name!r}; choose from {', '.join(init_choices())}")


@dataclass(frozen=True)
class LoadSummary:
    """Which of a network's tensors came from the pretrained file (``loaded``), which start fresh (``new``), and
    how many of the file's tensors found no place (``unused``)."""

    source: str
    loaded: tuple[str, ...]
    new: tuple[str, ...]
    unused: tuple[str, ...]

    @staticmethod
    def layers(names: tuple[str, ...]) -> list[str]:
        """The modules (tensor names without their last part) the tensors belong to, in order."""
        return list(dict.fromkeys(n.rsplit(".", 1)[0] for n in names))

    def text(self) -> str:
        """The printed summary: counts, and the top-level parts that start fresh."""
        fresh = list(dict.fromkeys(n.split(".")[0] if not n.startswith(("backbone.", "color.")) else
                                   ".".join(n.split(".")[:2]) for n in self.new))
        return (f"--init {self.source}: loaded {len(self.loaded)} tensors ({len(self.layers(self.loaded))} layers); "
                f"new {len(self.new)} tensors ({len(self.layers(self.new))} layers: {', '.join(fresh) or 'none'}); "
                f"{len(self.unused)} tensors of the file not used")


def load_matching(model: nn.Module, source: Mapping[str, torch.Tensor], rename: Callable[[str], str | None],
                  name: str) -> LoadSummary:
    """Copy every ``source`` tensor whose renamed key is one of ``model``'s with the same shape; the rest of the
    model keeps its initialisation.  FormatError when nothing matches (the wrong file or architecture)."""
    target = model.state_dict()
    picked: dict[str, torch.Tensor] = {}
    unused = []
    for key, value in source.items():
        dest = rename(key)
        if dest is not None and dest in target and tuple(target[dest].shape) == tuple(value.shape):
            picked[dest] = value.to(target[dest].dtype)
        else:
            unused.append(key)
    if not picked:
        raise FormatError(f"--init {name}: none of the pretrained tensors fits this network (different "
                          f"architecture or width)")
    model.load_state_dict(picked, strict=False)
    new = tuple(k for k in target if k not in picked)
    return LoadSummary(name, tuple(picked), new, tuple(unused))


def espnet_dir() -> Path:
    """Folder of the ESPNetv2 PASCAL files: ``$SEMMAP_PRETRAINED_DIR``, else the shipped ``weights/espnetv2``,
    else ``../shared/weights/espnetv2`` beside the repository."""
    from semmap.perception.registry import ESPNETV2_FOLDER, shipped_weights_dir

    env = os.environ.get(PRETRAINED_ENV)
    if env:
        return Path(env)
    shipped = shipped_weights_dir() / ESPNETV2_FOLDER
    return shipped if shipped.is_dir() else Path(__file__).resolve().parents[4].parent / ESPNET_SHARED_DIR


def load_espnet_encoder(model: nn.Module, name: str, folder: Path | None = None) -> LoadSummary:
    """The ESPNetv2 PASCAL encoder of ``--init name`` into ``model`` (whose ``encoder_prefix`` says where)."""
    from semmap.perception.networks.registry import check_finite_tensors, read_torch_file

    path = (folder or espnet_dir()) / ESPNET_FILES[ESPNET_INITS[name]]
    if not path.is_file():
        raise ConfigError(f"--init {name}: {path} not found (set {PRETRAINED_ENV} to the folder of the ESPNetv2 "
                          f"PASCAL weights)")
    prefix = getattr(model, "encoder_prefix", None)
    if prefix is None:
        raise ConfigError(f"--init {name}: {type(model).__name__} has no ESPNetv2 encoder")
    sd = read_torch_file(path, "ESPNetv2 weights file")
    if isinstance(sd, Mapping) and isinstance(sd.get("state_dict"), Mapping):
        sd = sd["state_dict"]
    if not isinstance(sd, Mapping):
        raise FormatError(f"{path}: expected a state dict of tensors")
    sd = {k.removeprefix("module."): v for k, v in sd.items()}
    check_finite_tensors(sd, path)
    return load_matching(model, sd, lambda k: prefix + k.removeprefix(ESPNET_ENCODER)
                         if k.startswith(ESPNET_ENCODER) else None, f"{name} ({path.name})")


def torchvision_state_dict(arch: str) -> dict:
    """torchvision's ImageNet weights of ``arch``, downloaded (or from torch's cache); one-line ConfigError when
    the machine cannot fetch them."""
    from urllib.error import URLError

    from semmap.perception.instances._torchvision_ops import import_torchvision

    weights = import_torchvision(f"--init {TORCHVISION}{arch}").models.get_model_weights(arch).IMAGENET1K_V1
    try:
        return dict(weights.get_state_dict(progress=False))
    except (URLError, OSError, RuntimeError) as exc:
        first = (str(exc).strip().splitlines() or [type(exc).__name__])[0][:120]
        raise ConfigError(f"--init {TORCHVISION}{arch}: cannot download torchvision's ImageNet weights from "
                          f"{weights.url} (offline? {first}); train from scratch or use --init espnetv2-pascal"
                          ) from None


def resnet_key(key: str) -> str | None:
    """torchvision ResNet tensor name -> semmap's :class:`~.resnet.ResNet` (None: the classifier)."""
    if key.startswith("fc."):
        return None
    for old, new in (("conv1.", "stem.0."), ("bn1.", "stem.1.")):
        if key.startswith(old):
            return new + key.removeprefix(old)
    return key.replace(".downsample.", ".shortcut.")


def vgg_keys(source: Mapping[str, torch.Tensor], block_prefix: str) -> dict[str, torch.Tensor]:
    """torchvision VGG-16 (no BN) -> semmap's VGG blocks (conv + BN): conv weights copied, each bias carried by
    the BN after it (unit scale, zero mean, variance 1 - eps), so the layer computes what the original did."""
    import torch

    from semmap.perception.networks.vgg import BLOCKS

    convs = sorted({int(k.split(".")[1]) for k in source if k.startswith("features.") and k.endswith(".weight")})
    slots = [(b, i) for b, (_, n) in enumerate(BLOCKS) for i in range(n)]
    out: dict[str, torch.Tensor] = {}
    for idx, (b, i) in zip(convs, slots, strict=False):
        w, bias = source[f"features.{idx}.weight"], source[f"features.{idx}.bias"]
        base = f"{block_prefix}{b}.{i}."
        out[base + "0.weight"] = w
        out[base + "1.weight"] = torch.ones_like(bias)
        out[base + "1.bias"] = bias
        out[base + "1.running_mean"] = torch.zeros_like(bias)
        out[base + "1.running_var"] = torch.full_like(bias, 1.0 - 1e-5)
    return out


def load_torchvision(model: nn.Module, name: str, source: Mapping[str, torch.Tensor] | None = None) -> LoadSummary:
    """torchvision's ``arch`` weights (``source``, else downloaded) into ``model``'s ResNet or VGG backbone."""
    arch = name.removeprefix(TORCHVISION)
    source = source if source is not None else torchvision_state_dict(arch)
    if arch.startswith("resnet"):
        return load_matching(model, source, lambda k: None if resnet_key(k) is None else "backbone." + resnet_key(k),
                             name)
    prefix = "backbone.blocks." if hasattr(getattr(model, "backbone", None), "blocks") else "color."
    mapped = vgg_keys(source, prefix)
    summary = load_matching(model, mapped, lambda k: k, name)
    used = {k for k in source if k.startswith("features.")}
    return LoadSummary(name, summary.loaded, summary.new, tuple(k for k in source if k not in used))


def load_pretrained(model: nn.Module, name: str) -> LoadSummary:
    """Load the pretrained start ``--init name`` into ``model`` and return the summary."""
    init_plan(name)
    if name in ESPNET_INITS:
        return load_espnet_encoder(model, name)
    if is_weight_file(name):
        from semmap.perception.networks.registry import load_weights

        source = load_weights(Path(name)).model.state_dict()
        return load_matching(model, source, lambda k: k, Path(name).name)
    return load_torchvision(model, name)
