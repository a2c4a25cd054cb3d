"""Segmenters by name, as ``semmap run --segmenter NAME [--weights PATH]`` selects them."""

from __future__ import annotations

import hashlib
import json
import logging
import os
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from semmap.errors import ConfigError, FormatError
from semmap.perception.base import Segmenter
from semmap.perception.networks.registry import MODELS
from semmap.registry import Registry
from semmap.types import LabelSet

log = logging.getLogger("semmap")

#: ESPNetv2's default network input: 320 px short side keeping the aspect ratio (432x320 for 640x480).
#: Measured on 24 7-Scenes frames (scripts/segmentation_grid.py, docs/images/): at 320 px the VOC weights find
#: chairs in 13 frames, monitors in 5 and the table in 16; at 384 px (512x384) chairs in only 8, and 384x384
#: loses much of the table. Indoor objects close to a Kinect look larger than in VOC's training crops.
ESPNETV2_INPUT = 320

#: Environment variable naming another folder of shipped weights.
WEIGHTS_ENV = "SEMMAP_WEIGHTS"
#: The shipped weights' manifest (sha256, training command, data seeds, metrics, the demo's network).
MANIFEST = "manifest.json"


def shipped_weights_dir() -> Path:
    """The repository's ``weights/`` folder (or ``$SEMMAP_WEIGHTS``)."""
    env = os.environ.get(WEIGHTS_ENV)
    return Path(env) if env else Path(__file__).resolve().parents[3] / "weights"


def demo_network() -> str | None:
    """The shipped network ``semmap demo`` segments with: ``demo.network`` of ``weights/manifest.json`` (the
    best MIoU per millisecond), or None when the manifest or its weight file is missing."""
    path = shipped_weights_dir() / MANIFEST
    try:
        name = json.loads(path.read_text())["demo"]["network"]
    except (OSError, ValueError, KeyError, TypeError):
        return None
    return name if name in TRAINED_NETWORKS and shipped_weights(name).is_file() else None


def shipped_weights(name: str) -> Path:
    """Path of the shipped weight file of network ``name`` (``weights/<name>.pt``)."""
    return shipped_weights_dir() / f"{name}.pt"


#: The shipped ESPNetv2 PASCAL VOC weights (MIT licence, ``weights/espnetv2/LICENSE``), by width.
ESPNETV2_FOLDER = "espnetv2"
ESPNETV2_FILES = {"s1": "espnetv2_s_1.0_pascal_384x384.pth", "s2": "espnetv2_s_2.0_pascal_384x384.pth"}
#: The width ``--segmenter espnetv2`` runs without ``--weights``.
ESPNETV2_DEFAULT = "s2"


def shipped_espnetv2(size: str = ESPNETV2_DEFAULT) -> Path:
    """Path of a shipped ESPNetv2 PASCAL weight file (``weights/espnetv2/espnetv2_s_2.0_pascal_384x384.pth``)."""
    return shipped_weights_dir() / ESPNETV2_FOLDER / ESPNETV2_FILES[size]


def _manifest_entry(path: Path) -> tuple[Path, dict | None]:
    """The manifest of the shipped weights and its entry for the file ``path`` (None when it is not listed)."""
    manifest = shipped_weights_dir() / MANIFEST
    try:
        networks = json.loads(manifest.read_text())["networks"]
    except FileNotFoundError:
        return manifest, None
    except (OSError, ValueError, KeyError, TypeError, UnicodeDecodeError) as exc:
        raise FormatError(f"{manifest}: unreadable weights manifest ({type(exc).__name__})") from None
    try:  # the weights semmap ships but did not train (ESPNetv2's authors' files)
        external = json.loads(manifest.read_text()).get("external", {})
    except (OSError, ValueError, AttributeError):
        external = {}
    target = path.resolve()
    entries = [*(networks.values() if isinstance(networks, dict) else ()),
               *(external.values() if isinstance(external, dict) else ())]
    for entry in entries:
        if isinstance(entry, dict) and (manifest.parent / str(entry.get("file", ""))).resolve() == target:
            return manifest, entry
    return manifest, None


def _sha256(path: Path) -> str:
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()


def verify_weights(path: Path, *, shipped: bool, trust: bool = False) -> None:
    """Check a weight file against the sha256 of ``weights/manifest.json`` when it is a shipped network's or listed
    there: a changed or unlisted file is refused (ConfigError), or used with a warning when ``trust`` is set."""
    manifest, entry = _manifest_entry(path)
    if entry is None and not shipped:
        return  # the user's own weights (e.g. RUN/best.pt): nothing to check them against
    if entry is None:
        problem = f"not listed in {manifest}"
    else:
        expected, actual = str(entry.get("sha256", "")), _sha256(path)
        if actual == expected:
            return
        problem = f"sha256 {actual[:12]}... differs from {manifest} ({expected[:12]}...)"
    if not trust:
        raise ConfigError(f"{path}: {problem}; the weights were changed or replaced: restore them, or pass "
                          f"--trust-weights to use them anyway")
    log.warning("%s: %s; used anyway (--trust-weights)", path, problem)


@dataclass(frozen=True)
class SegmenterEntry:
    """A segmenter by name: its factory (the keywords of :func:`make_segmenter`), one line of help, and what it
    needs."""

    name: str
    factory: Callable[..., Segmenter]
    help: str
    needs_weights: bool = False  #: ``--weights`` is required (no shipped default)
    trained: bool = False  #: one of semmap's own networks (its weight file holds architecture and label set)
    uses_depth: bool = False  #: reads the depth image too
    dataset_classes: bool = False  #: predicts the dataset's own label set (needs it opened first; precomputed:
    #: unless its folder has a labelset.json)
    takes_model: bool = False  #: the user's own model, named after a colon: ``NAME:MODEL`` (a file, hub id, folder)


def _oracle(*, label_set: LabelSet | None, k: int, oracle_preset: str, seed: int, **_) -> Segmenter:
    from semmap.perception.oracle import OracleSegmenter

    if label_set is None:
        from semmap.labels import INDOOR_LABELS

        label_set = INDOOR_LABELS
    return OracleSegmenter(label_set, preset=oracle_preset, seed=seed, k=k)


def _precomputed(*, weights: Path | None, label_set: LabelSet | None, k: int, label_confidence: float,
                 **_) -> Segmenter:
    from semmap.perception.precomputed import PrecomputedSegmenter

    if weights is None:
        raise ConfigError("--segmenter precomputed needs the predictions folder: --weights FOLDER")
    return PrecomputedSegmenter(weights, label_set=label_set, k=k, label_confidence=label_confidence)


def _espnetv2(*, weights: Path | None, k: int, backend: str, batch_size: int,
              input_size: tuple[int, int] | int | None, threads: int | None, trust_weights: bool = False,
              calibration: bool = True, **_) -> Segmenter:
    from semmap.perception.espnetv2 import espnetv2_meta, load_espnetv2
    from semmap.perception.network import NetworkInput, NetworkSegmenter
    from semmap.perception.voc import PASCAL_VOC

    shipped = weights is None
    if shipped:
        weights = shipped_espnetv2()
        if not weights.is_file():
            raise ConfigError(f"--segmenter espnetv2: no shipped weights at {weights}; pass --weights "
                              f"espnetv2_s_2.0_pascal_384x384.pth")
    if Path(weights).is_file():
        verify_weights(Path(weights), shipped=shipped, trust=trust_weights)
    model = load_espnetv2(weights, full_resolution=False)  # the segmenter upsamples once, to the image
    size = ESPNETV2_INPUT if input_size is None else input_size
    net_input = NetworkInput(short_side=size) if isinstance(size, int) else NetworkInput(size=size)
    stat = Path(weights).stat()
    temperature = weights_temperature(espnetv2_meta(weights), Path(weights)) if calibration and not shipped else 1.0
    return NetworkSegmenter(model, PASCAL_VOC, name=ESPNETV2, net_input=net_input, k=k, backend=backend,
                            batch_size=batch_size, threads=threads, temperature=temperature,
                            cache_key=f"{Path(weights).resolve()}|{stat.st_size}|{stat.st_mtime_ns}|half")


def _trained(name: str) -> Callable[..., Segmenter]:
    def make(*, weights: Path | None, k: int, backend: str, batch_size: int,
             input_size: tuple[int, int] | int | None, threads: int | None, trust_weights: bool = False,
             calibration: bool = True, **_) -> Segmenter:
        return trained_network_segmenter(name, weights=weights, k=k, backend=backend, batch_size=batch_size,
                                         input_size=input_size, threads=threads, trust_weights=trust_weights,
                                         calibration=calibration)

    return make


def _structure(*, k: int, up_world=None, **_) -> Segmenter:
    from semmap.perception.structure.segmenter import StructureSegmenter

    return StructureSegmenter(k=k, up_world=up_world)


def _user_model(name: str) -> Callable[..., Segmenter]:
    """The factory of a segmenter around the user's own model (``onnx:MODEL.onnx``, ``hf:MODEL_ID``)."""

    def make(*, model: str | None, model_config: Path | None, class_map: Path | None, k: int, backend: str,
             batch_size: int, input_size: tuple[int, int] | int | None, threads: int | None, weights: Path | None,
             **_) -> Segmenter:
        if weights is not None:
            raise ConfigError(f"--segmenter {name}:MODEL takes no --weights: the model holds its own")
        if not model:
            example = "MODEL.onnx" if name == ONNX else "MODEL_ID_OR_FOLDER"
            raise ConfigError(f"--segmenter {name} needs the model after a colon: --segmenter {name}:{example}")
        if name == ONNX:
            from semmap.perception.user_models import onnx_segmenter

            return onnx_segmenter(name, Path(model), config=model_config, class_map=class_map, k=k,
                                  batch_size=batch_size, threads=threads, input_size=input_size)
        if model_config is not None:
            raise ConfigError(f"--segmenter-config is the sidecar of an {ONNX}: model; hf: models describe "
                              "themselves (config.json, preprocessor_config.json)")
        if backend != "torch":
            raise ConfigError(f"--segmenter {name} runs in PyTorch; --backend {backend} is for semmap's own networks")
        from semmap.perception.hf_models import hf_segmenter

        return hf_segmenter(name, model, class_map=class_map, k=k, batch_size=batch_size, threads=threads,
                            input_size=input_size)

    return make


#: The PASCAL VOC network loaded from its authors' weights.
ESPNETV2 = "espnetv2"
#: Wall, floor and ceiling from depth and gravity; ``NAME+structure`` adds them to any segmenter.
STRUCTURE = "structure"
STRUCTURE_SUFFIX = "+structure"
#: A user's ONNX model with a JSON sidecar, and a Hugging Face transformers model.
ONNX, HUGGING_FACE = "onnx", "hf"
#: Every segmenter ``--segmenter`` can name: three of their own, then semmap's trained networks
#: (:data:`~semmap.perception.networks.registry.MODELS`, shipped weights in ``weights/<name>.pt``).
SEGMENTERS: Registry[SegmenterEntry] = Registry("segmenter", [
    SegmenterEntry("oracle", _oracle, "simulated network made from ground-truth labels (simulator sequences)",
                   dataset_classes=True),
    SegmenterEntry("precomputed", _precomputed, "per-frame label PNGs or .npy/.npz probabilities from a folder "
                   "(--weights FOLDER)", needs_weights=True, dataset_classes=True),
    SegmenterEntry(ESPNETV2, _espnetv2, "ESPNetv2 trained on PASCAL VOC, 21 classes (shipped "
                   "weights/espnetv2/, or --weights espnetv2_s_1.0_pascal_384x384.pth)"),
    SegmenterEntry(STRUCTURE, _structure, "wall, floor and ceiling from depth and gravity, any recording (NAME+"
                   "structure: with a network's classes, e.g. espnetv2+structure)"),
    SegmenterEntry(ONNX, _user_model(ONNX), "your ONNX segmentation model: onnx:MODEL.onnx, described by "
                   "MODEL.json or --segmenter-config (docs/segmenters.md)", takes_model=True),
    SegmenterEntry(HUGGING_FACE, _user_model(HUGGING_FACE), "a Hugging Face transformers segmentation model: "
                   "hf:MODEL_ID or hf:FOLDER (pip install semmap[hub])", takes_model=True),
    *(SegmenterEntry(m.name, _trained(m.name), f"{m.help}, trained by semmap (shipped weights/{m.name}.pt, or "
                     f"--weights RUN/best.pt)", trained=True, uses_depth=m.uses_depth) for m in MODELS.values()),
])
#: Segmenters that are semmap's own trained networks (their weight files hold architecture and label set).
TRAINED_NETWORKS: tuple[str, ...] = SEGMENTERS.where(trained=True)
#: The segmenter names as an enum (the type of ``semantics.segmenter`` in the run configuration).
SegmenterName = SEGMENTERS.enum("SegmenterName", __name__)


def split_structure(text: str) -> tuple[str, bool]:
    """``"espnetv2+structure"`` -> ("espnetv2", True); a name without the suffix -> (name, False)."""
    text = str(text)
    if text.endswith(STRUCTURE_SUFFIX) and len(text) > len(STRUCTURE_SUFFIX):
        return text[: -len(STRUCTURE_SUFFIX)], True
    return text, False


def split_segmenter(text: str) -> tuple[str, str | None]:
    """``"onnx:model.onnx"`` -> ("onnx", "model.onnx"); a name without a model -> (name, None)."""
    text, _ = split_structure(text)
    name, sep, model = str(text).partition(":")
    if sep and name in SEGMENTERS and SEGMENTERS[name].takes_model:
        return name, model
    return str(text), None


def make_segmenter(name: str, *, weights: Path | None = None, label_set: LabelSet | None = None, k: int = 3,
                   label_confidence: float = 0.9, oracle_preset: str = "cnn-like", seed: int = 0,
                   backend: str = "torch", batch_size: int = 1, input_size: tuple[int, int] | int | None = None,
                   threads: int | None = None, trust_weights: bool = False, model: str | None = None,
                   model_config: Path | None = None, class_map: Path | None = None,
                   calibration: bool = True, structure: bool = False, up_world=None) -> Segmenter:
    """Build the segmenter ``name`` (``NAME:MODEL`` for the user's own model, or ``model``); ``label_set`` is the
    dataset's (the oracle predicts its classes); ``trust_weights`` uses shipped weights whose sha256 differs from
    the manifest (with a warning); ``model_config`` is an ONNX model's sidecar and ``class_map`` folds a user
    model's classes into the map's; ``calibration=False`` ignores a trained network's temperature.
    ``structure`` (or ``NAME+structure``) adds wall, floor and ceiling from geometry to the segmenter's classes,
    ``up_world`` is a gravity-aligned world frame's up axis for the structure segmenter (``--up``)."""
    name, suffixed = split_structure(name)
    structure = structure or suffixed
    name, named_model = split_segmenter(name)
    entry = SEGMENTERS[name]
    if structure and name == STRUCTURE:
        raise ConfigError("--segmenter structure+structure: name a network before +structure (espnetv2+structure)")
    if not entry.takes_model and (model or model_config is not None or class_map is not None):
        raise ConfigError(f"--segmenter {name}: a model, --segmenter-config and --class-map are for the user's own "
                          f"model ({', '.join(n + ':MODEL' for n in SEGMENTERS.where(takes_model=True))})")
    segmenter = entry.factory(weights=weights, label_set=label_set, k=k, label_confidence=label_confidence,
                              oracle_preset=oracle_preset, seed=seed, backend=backend, batch_size=batch_size,
                              input_size=input_size, threads=threads, trust_weights=trust_weights,
                              model=named_model or model, model_config=model_config, class_map=class_map,
                              calibration=calibration, up_world=up_world)
    if not structure:
        return segmenter
    from semmap.perception.structure.compose import WithStructure
    from semmap.perception.structure.segmenter import StructureSegmenter

    return WithStructure(segmenter, StructureSegmenter(k=k, up_world=up_world), k=k)


def trained_network_segmenter(name: str, *, weights: Path | None = None, k: int = 3, backend: str = "torch",
                              batch_size: int = 1, input_size: tuple[int, int] | int | None = None,
                              threads: int | None = None, trust_weights: bool = False,
                              calibration: bool = True) -> Segmenter:
    """A segmenter running one of semmap's trained networks from its weight file (default: the shipped one,
    checked against the manifest's sha256), at the input size it was trained at unless ``input_size`` says
    otherwise; its probabilities use the temperature stored with the weights unless ``calibration`` is off."""
    import cv2

    from semmap.perception.network import NetworkInput, NetworkSegmenter
    from semmap.perception.networks.registry import load_weights

    path = Path(weights) if weights is not None else shipped_weights(name)
    if weights is None and not path.is_file():
        raise ConfigError(f"--segmenter {name}: no shipped weights at {path}; train them (semmap train) and pass "
                          f"--weights RUN_DIR/best.pt")
    if path.is_file():
        verify_weights(path, shipped=weights is None, trust=trust_weights)
    loaded = load_weights(path)
    if loaded.spec.model != name:
        raise ConfigError(f"{path}: holds a {loaded.spec.model} network, not {name}")
    size = loaded.input_size if input_size is None else input_size
    net_input = (NetworkInput(short_side=size, interpolation=cv2.INTER_AREA) if isinstance(size, int)
                 else NetworkInput(size=tuple(size), short_side=None, interpolation=cv2.INTER_AREA))
    stat = path.stat()
    return NetworkSegmenter(loaded.model, loaded.label_set, name=name, net_input=net_input, k=k, backend=backend,
                            batch_size=batch_size, threads=threads,
                            cache_key=f"{path.resolve()}|{stat.st_size}|{stat.st_mtime_ns}",
                            temperature=weights_temperature(loaded.meta, path) if calibration else 1.0)


def weights_temperature(meta: dict, path: Path) -> float:
    """The calibration temperature stored in a weight file's metadata (1 when it has none)."""
    t = meta.get("temperature", 1.0)
    if isinstance(t, bool) or not isinstance(t, int | float) or not (0 < t < float("inf")):
        raise FormatError(f"{path}: calibration temperature {t!r} in the metadata is not a positive number")
    return float(t)
