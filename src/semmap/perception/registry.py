"""Segmenters by name, as ``semmap run --segmenter NAME [--weights PATH]`` selects them."""

from __future__ import annotations

import os
from pathlib import Path

from semmap.errors import ConfigError
from semmap.perception.base import Segmenter
from semmap.types import LabelSet

#: ESPNetv2's default network input: 320 px short side keeping the aspect ratio (432x320 for 640x480).
#: Measured on 24 7-Scenes frames (scripts/segmentation_grid.py, docs/images/): at 320 px the VOC weights find
#: chairs in 13 frames, monitors in 5 and the table in 16; at 384 px (512x384) chairs in only 8, and 384x384
#: loses much of the table. Indoor objects close to a Kinect look larger than in VOC's training crops.
ESPNETV2_INPUT = 320

#: name -> what it needs, for help texts and errors.
SEGMENTERS = {
    "oracle": "simulated network made from ground-truth labels (simulator sequences)",
    "precomputed": "per-frame label PNGs or .npy/.npz probabilities from a folder (--weights FOLDER)",
    "espnetv2": "ESPNetv2 trained on PASCAL VOC, 21 classes (--weights espnetv2_s_2.0_pascal_384x384.pth)",
    "fcn": "FCN-8s trained by semmap on simulated scenes (shipped weights/fcn.pt, or --weights RUN/best.pt)",
    "pspnet": "PSPNet trained by semmap (weights/pspnet.pt)",
    "cbam-pspnet": "CBAM-PSPNet trained by semmap (weights/cbam-pspnet.pt)",
    "rgbd-net": "the RGB-D multi-scale network trained by semmap, colour + depth (weights/rgbd-net.pt)",
    "rgb-only": "the RGB-D network's colour-only twin trained by semmap (weights/rgb-only.pt)",
}
#: Segmenters that are semmap's own trained networks (their weight files hold architecture and label set).
TRAINED_NETWORKS = ("fcn", "pspnet", "cbam-pspnet", "rgbd-net", "rgb-only")
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
    import json

    path = shipped_weights_dir() / MANIFEST
    try:
        name = json.loads(path.read_text())["demo"]["network"]
    except (OSError, ValueError, KeyError, TypeError):
        return None
    return name if name in TRAINED_NETWORKS and shipped_weights(name).is_file() else None


def shipped_weights(name: str) -> Path:
    """Path of the shipped weight file of network ``name`` (``weights/<name>.pt``)."""
    return shipped_weights_dir() / f"{name}.pt"


def make_segmenter(name: str, *, weights: Path | None = None, label_set: LabelSet | None = None, k: int = 3,
                   label_confidence: float = 0.9, oracle_preset: str = "cnn-like", seed: int = 0,
                   backend: str = "torch", batch_size: int = 1, input_size: tuple[int, int] | int | None = None,
                   threads: int | None = None) -> Segmenter:
    """Build the segmenter ``name``; ``label_set`` is the dataset's (the oracle predicts its classes)."""
    if name == "oracle":
        from semmap.perception.oracle import OracleSegmenter

        if label_set is None:
            from semmap.labels import INDOOR_LABELS

            label_set = INDOOR_LABELS
        return OracleSegmenter(label_set, preset=oracle_preset, seed=seed, k=k)
    if name == "precomputed":
        from semmap.perception.precomputed import PrecomputedSegmenter

        if weights is None:
            raise ConfigError("--segmenter precomputed needs the predictions folder: --weights FOLDER")
        return PrecomputedSegmenter(weights, k=k, label_confidence=label_confidence)
    if name == "espnetv2":
        from semmap.perception.espnetv2 import load_espnetv2
        from semmap.perception.network import NetworkInput, NetworkSegmenter
        from semmap.perception.voc import PASCAL_VOC

        if weights is None:
            raise ConfigError("--segmenter espnetv2 needs its weights: --weights espnetv2_s_2.0_pascal_384x384.pth")
        model = load_espnetv2(weights, full_resolution=False)  # the segmenter upsamples once, to the image
        size = ESPNETV2_INPUT if input_size is None else input_size
        net_input = NetworkInput(short_side=size) if isinstance(size, int) else NetworkInput(size=size)
        stat = Path(weights).stat()
        return NetworkSegmenter(model, PASCAL_VOC, name="espnetv2", net_input=net_input, k=k, backend=backend,
                                batch_size=batch_size, threads=threads,
                                cache_key=f"{Path(weights).resolve()}|{stat.st_size}|{stat.st_mtime_ns}|half")
    if name in TRAINED_NETWORKS:
        return trained_network_segmenter(name, weights=weights, k=k, backend=backend, batch_size=batch_size,
                                         input_size=input_size, threads=threads)
    raise ConfigError(f"unknown segmenter {name!r}; choose one of {', '.join(SEGMENTERS)}")


def trained_network_segmenter(name: str, *, weights: Path | None = None, k: int = 3, backend: str = "torch",
                              batch_size: int = 1, input_size: tuple[int, int] | int | None = None,
                              threads: int | None = None) -> Segmenter:
    """A segmenter running one of semmap's trained networks from its weight file (default: the shipped one),
    at the input size it was trained at unless ``input_size`` says otherwise."""
    import cv2

    from semmap.perception.network import NetworkInput, NetworkSegmenter
    from semmap.perception.networks.registry import load_weights

    path = Path(weights) if weights is not None else shipped_weights(name)
    if weights is None and not path.is_file():
        raise ConfigError(f"--segmenter {name}: no shipped weights at {path}; train them (semmap train) and pass "
                          f"--weights RUN_DIR/best.pt")
    loaded = load_weights(path)
    if loaded.spec.model != name:
        raise ConfigError(f"{path}: holds a {loaded.spec.model} network, not {name}")
    size = loaded.input_size if input_size is None else input_size
    net_input = (NetworkInput(short_side=size, interpolation=cv2.INTER_AREA) if isinstance(size, int)
                 else NetworkInput(size=tuple(size), short_side=None, interpolation=cv2.INTER_AREA))
    stat = path.stat()
    return NetworkSegmenter(loaded.model, loaded.label_set, name=name, net_input=net_input, k=k, backend=backend,
                            batch_size=batch_size, threads=threads,
                            cache_key=f"{path.resolve()}|{stat.st_size}|{stat.st_mtime_ns}")
