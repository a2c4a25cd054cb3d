"""Segmenters by name, as ``semmap run --segmenter NAME [--weights PATH]`` selects them."""

from __future__ import annotations

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
}


def make_segmenter(name: str, *, weights: Path | None = None, label_set: LabelSet | None = None, k: int = 3,
                   label_confidence: float = 0.9, oracle_preset: str = "cnn-like", seed: int = 0,
                   backend: str = "torch", batch_size: int = 1, input_size: tuple[int, int] | int | None = None,
                   threads: int | None = None) -> Segmenter:
    """Build the segmenter ``name``; ``label_set`` is the dataset's (the oracle predicts its classes)."""
    if name == "oracle":
        from semmap.perception.oracle import OracleSegmenter

        if label_set is None:
            from semmap.sim.labels import INDOOR_LABELS

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
    raise ConfigError(f"unknown segmenter {name!r}; choose one of {', '.join(SEGMENTERS)}")
