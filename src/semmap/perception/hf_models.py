"""Hugging Face ``transformers`` semantic segmentation as a segmenter (``--segmenter hf:MODEL_ID_OR_FOLDER``).

SegFormer and the other ``AutoModelForSemanticSegmentation`` models give class logits; Mask2Former, MaskFormer and
OneFormer give masks and their classes, from which the semantic scores are the sum over queries of each query's
class probability times its mask probability (what the image processor's ``post_process_semantic_segmentation``
takes the argmax of), normalised per pixel here. The label set is the model's ``config.id2label``; the image
processor's size, mean and std feed it. An optional extra: ``pip install semmap[hub]``. A model id is fetched from
the hub (or the local hub cache) by ``transformers``; with ``HF_HUB_OFFLINE=1`` only the cache is read.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from semmap.errors import ConfigError
from semmap.perception.network import IMAGENET_MEAN, IMAGENET_STD, NetworkInput
from semmap.perception.user_models import ModelOutput, ModelSegmenter, class_fold

log = logging.getLogger("semmap")

#: ``config.model_type`` of the mask-classification models whose semantic output is built from their queries.
UNIVERSAL_TYPES = ("mask2former", "maskformer", "oneformer")
#: Network input when the model comes without an image processor (SegFormer's ADE20K size).
DEFAULT_SIZE = (512, 512)
HUB_HINT = "pip install 'semmap[hub]' (transformers)"


def _transformers():
    """The ``transformers`` module, quiet, or a ConfigError saying how to install it."""
    try:
        from semmap.perception.instances._torchvision_ops import import_torchvision

        import_torchvision()  # transformers imports torchvision when it is there: with working operators
    except ConfigError:
        pass  # no torchvision: transformers does without
    try:
        import transformers
    except ImportError:
        raise ConfigError(f"--segmenter hf: needs the transformers package: {HUB_HINT}") from None
    transformers.logging.set_verbosity_error()
    transformers.utils.logging.disable_progress_bar()
    try:
        import huggingface_hub

        huggingface_hub.utils.logging.set_verbosity_error()  # no "Retrying in 8s" lines: one error at the end
    except (ImportError, AttributeError):
        pass
    return transformers


def _offline() -> bool:
    return os.environ.get("HF_HUB_OFFLINE", "").strip().lower() in ("1", "true", "yes", "on")


def _load(what: str, model_id: str, loader, **kwargs):
    """``loader.from_pretrained(model_id)``, or one line saying why not (offline, no such model, not a model)."""
    local = Path(model_id).is_dir()
    try:
        try:  # the local folder, or the hub cache first: no network where the model is already there
            return loader.from_pretrained(model_id, local_files_only=True, **kwargs)
        except OSError:
            if local or _offline():
                raise
        return loader.from_pretrained(model_id, **kwargs)
    except (OSError, ValueError, KeyError, TypeError) as exc:
        first = (str(exc).strip().splitlines() or [type(exc).__name__])[0][:200]
        if local:
            raise ConfigError(f"{model_id}: cannot load the {what} of this transformers model folder ({first})"
                              ) from None
        if _offline() or "connect" in str(exc).lower() or "offline" in str(exc).lower():
            raise ConfigError(f"hf:{model_id}: the model is not in the local Hugging Face cache and the hub cannot "
                              "be reached (offline); download it where the hub is reachable, save it with "
                              "save_pretrained and pass hf:FOLDER") from None
        raise ConfigError(f"hf:{model_id}: cannot load the {what} ({first})") from None


def _class_names(config, model_id: str) -> tuple[str, ...]:
    """The model's classes in id order from ``config.id2label``."""
    id2label = {int(k): str(v) for k, v in (getattr(config, "id2label", None) or {}).items()}
    if not id2label or sorted(id2label) != list(range(len(id2label))):
        raise ConfigError(f"hf:{model_id}: config.id2label must name every class id 0..K-1")
    return tuple(id2label[i] for i in range(len(id2label)))


def _net_input(processor, input_size: tuple[int, int] | int | None) -> NetworkInput:
    """Size and normalisation from the image processor (or ``--input-size``; ImageNet's without a processor)."""
    mean = tuple(getattr(processor, "image_mean", None) or IMAGENET_MEAN)
    std = tuple(getattr(processor, "image_std", None) or IMAGENET_STD)
    if processor is not None and not getattr(processor, "do_normalize", True):
        mean, std = (0.0, 0.0, 0.0), (1.0, 1.0, 1.0)
    scale = float(getattr(processor, "rescale_factor", 1 / 255)) * 255.0
    if processor is not None and not getattr(processor, "do_rescale", True):
        scale = 255.0
    mean, std = tuple(m / scale for m in mean), tuple(s / scale for s in std)
    if input_size is not None:
        if isinstance(input_size, int):
            return NetworkInput(short_side=input_size, multiple=32, mean=mean, std=std)
        return NetworkInput(size=tuple(input_size), short_side=None, mean=mean, std=std)
    size = getattr(processor, "size", None) or {}
    get = size.get if hasattr(size, "get") else lambda key: getattr(size, key, None)
    if get("height") and get("width"):
        return NetworkInput(size=(int(get("width")), int(get("height"))), short_side=None, mean=mean, std=std)
    if get("shortest_edge"):
        return NetworkInput(short_side=int(get("shortest_edge")), multiple=32, mean=mean, std=std)
    return NetworkInput(size=DEFAULT_SIZE, short_side=None, mean=mean, std=std)


def _task_inputs(transformers, model_id: str, torch):
    """OneFormer's text input for the semantic task, tokenised by its processor."""
    processor = _load("processor", model_id, transformers.AutoProcessor)
    dummy = np.zeros((32, 32, 3), np.uint8)
    return processor(images=[dummy], task_inputs=["semantic"], return_tensors="pt")["task_inputs"]


def hf_segmenter(name: str, model_id: str, *, class_map: Path | None = None, k: int = 3, batch_size: int = 1,
                 threads: int | None = None, input_size: tuple[int, int] | int | None = None) -> ModelSegmenter:
    """A segmenter running the ``transformers`` model ``model_id`` (a hub id or a save_pretrained folder)."""
    transformers = _transformers()
    import torch

    config = _load("configuration", model_id, transformers.AutoConfig)
    universal = getattr(config, "model_type", "") in UNIVERSAL_TYPES
    loader = transformers.AutoModelForUniversalSegmentation if universal else \
        transformers.AutoModelForSemanticSegmentation
    model = _load("model", model_id, loader).eval()
    try:
        processor = _load("image processor", model_id, transformers.AutoImageProcessor)
    except ConfigError as exc:
        log.warning("%s; using ImageNet normalisation at %dx%d", exc, *DEFAULT_SIZE)
        processor = None
    net_input = _net_input(processor, input_size)
    names = _class_names(model.config, model_id)
    task = _task_inputs(transformers, model_id, torch) if config.model_type == "oneformer" else None
    if threads is not None:
        torch.set_num_threads(int(threads))

    def run(rgbs: Sequence[np.ndarray]) -> ModelOutput:
        x = torch.from_numpy(net_input.batch(rgbs))
        with torch.inference_mode():
            if not universal:
                return ModelOutput(model(pixel_values=x).logits.float().numpy(), "logits")
            extra = {} if task is None else {"task_inputs": task.repeat(len(rgbs), 1)}
            out = model(pixel_values=x, **extra)
            classes = out.class_queries_logits.float().softmax(-1)[..., :-1]  # the last class is "no object"
            masks = out.masks_queries_logits.float().sigmoid()
            return ModelOutput(torch.einsum("bqc,bqhw->bchw", classes, masks).numpy(), "probabilities")

    fold = class_fold(names, class_map, f"hf:{model_id} config.id2label")
    return ModelSegmenter(name, run, net_input, fold, k=k, batch_size=batch_size, what=f"hf:{model_id}")
