"""Runs a dense-prediction network as a segmenter: resize, normalise, batch, infer, resize back, top-k.

The network itself is any ``torch.nn.Module`` mapping (N, 3, h, w) normalised RGB to (N, K, h', w') logits -
and, when the module says ``uses_depth``, a second input (N, 1, h, w) of depth in metres (the RGB-D network);
:class:`NetworkSegmenter` does everything around it, so new architectures slot in by providing a module.
Inference runs in PyTorch or, when faster, in ONNX Runtime from an ONNX file exported once and cached.
"""

from __future__ import annotations

import hashlib
import logging
import os
import time
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from semmap.errors import ConfigError
from semmap.geometry import onto_depth_grid
from semmap.limits import check_network_input, parse_sides
from semmap.types import EMPTY_LABEL, Frame, LabelSet, TopKProbs

log = logging.getLogger("semmap")

IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)
BACKENDS = ("torch", "onnx")


@dataclass(frozen=True)
class NetworkInput:
    """How images are fed to a network: a fixed ``size`` (width, height) when given, else scaled to ``short_side``
    pixels keeping the aspect ratio (sides rounded to a multiple of ``multiple``); RGB in [0, 1] normalised per
    channel."""

    size: tuple[int, int] | None = None
    short_side: int | None = 384
    multiple: int = 16
    mean: tuple[float, float, float] = IMAGENET_MEAN
    std: tuple[float, float, float] = IMAGENET_STD
    #: how colour is reduced: ``cv2.INTER_AREA`` (pixel-area averaging, what semmap's own networks train on) or
    #: ``cv2.INTER_LINEAR`` (what ESPNetv2's measurements were made with)
    interpolation: int = cv2.INTER_LINEAR

    def __post_init__(self) -> None:
        if self.size is None and self.short_side is None:
            raise ConfigError("network input needs a fixed size or a short side")
        if self.size is not None and min(self.size) < 16:
            raise ConfigError(f"network input size must be at least 16x16, got {self.size[0]}x{self.size[1]}")
        if self.short_side is not None and self.short_side < 16:
            raise ConfigError(f"network input short side must be at least 16 pixels, got {self.short_side}")

    def size_for(self, width: int, height: int) -> tuple[int, int]:
        """(width, height) of the network input for an image of ``width`` x ``height``."""
        if self.size is not None:
            return self.size
        f = self.short_side / min(width, height)
        m = self.multiple
        return max(m, int(width * f / m + 0.5) * m), max(m, int(height * f / m + 0.5) * m)

    def batch(self, rgbs: Sequence[np.ndarray]) -> np.ndarray:
        """(N, 3, h, w) float32 network input from equally sized (H, W, 3) uint8 RGB images."""
        w, h = self.size_for(rgbs[0].shape[1], rgbs[0].shape[0])
        out = np.empty((len(rgbs), 3, h, w), np.float32)
        scale = np.float32(1.0 / 255.0)
        mean = np.asarray(self.mean, np.float32)
        inv_std = 1.0 / np.asarray(self.std, np.float32)
        for i, rgb in enumerate(rgbs):
            interp = self.interpolation
            if interp == cv2.INTER_AREA and (rgb.shape[0] < h or rgb.shape[1] < w):
                interp = cv2.INTER_LINEAR  # enlarging: nothing to average
            img = cv2.resize(rgb, (w, h), interpolation=interp) if rgb.shape[:2] != (h, w) else rgb
            out[i] = ((img.astype(np.float32) * scale - mean) * inv_std).transpose(2, 0, 1)
        return out

    def depth_batch(self, depths: Sequence[np.ndarray], image_shape: tuple[int, int]) -> np.ndarray:
        """(N, 1, h, w) float32 depth in metres (0 = invalid) at the network input size of images of
        ``image_shape`` (H, W), resized by nearest neighbour (no depths invented across edges)."""
        w, h = self.size_for(image_shape[1], image_shape[0])
        out = np.empty((len(depths), 1, h, w), np.float32)
        for i, d in enumerate(depths):
            d = np.nan_to_num(np.asarray(d, np.float32), nan=0.0, posinf=0.0, neginf=0.0)
            out[i, 0] = cv2.resize(d, (w, h), interpolation=cv2.INTER_NEAREST) if d.shape != (h, w) else d
        return out


def parse_input_size(text: str | None) -> tuple[int, int] | int | None:
    """Network input from the command line: ``"512x384"`` -> (512, 384); ``"384"`` -> 384 (the short side)."""
    return None if text is None else parse_sides(text, "--input-size", short_side=True)


def _check_input_budget(net_input: NetworkInput, batch: int) -> None:
    """Refuse an input size whose batch would not fit the memory budget (a 4:3 image for a short side)."""
    if net_input.size is not None:
        check_network_input(*net_input.size, batch)
    elif net_input.short_side is not None:
        check_network_input(net_input.short_side * 4 // 3, net_input.short_side, batch)


class NetworkSegmenter:
    """:class:`~semmap.perception.base.Segmenter` around a network predicting logits over ``label_set``."""

    def __init__(self, model, label_set: LabelSet, *, name: str, net_input: NetworkInput = NetworkInput(),
                 k: int = 3, batch_size: int = 4, backend: str = "torch", threads: int | None = None,
                 cache_dir: Path | None = None, cache_key: str = "", temperature: float = 1.0):
        if backend not in BACKENDS:
            raise ConfigError(f"segmenter backend must be one of {BACKENDS}, got {backend!r}")
        if k < 1:
            raise ConfigError(f"k must be at least 1, got {k}")
        import torch

        self.name = name
        self._label_set = label_set
        self.net_input = net_input
        self.k = k
        self.batch_size = max(1, int(batch_size))
        self.backend = backend
        _check_input_budget(net_input, self.batch_size)
        self._torch = torch
        if threads is not None:
            torch.set_num_threads(int(threads))
        self._model = model.eval()
        self._threads = threads
        self._cache_dir, self._cache_key = cache_dir, cache_key
        if not (np.isfinite(temperature) and temperature > 0):
            raise ConfigError(f"{name}: calibration temperature must be a positive number, got {temperature}")
        #: the network's calibration temperature: probabilities are softmax(logits / temperature)
        self.temperature = float(temperature)
        self._sessions: dict[tuple[int, ...], object] = {}  # ONNX graphs are traced for one input shape

    @property
    def label_set(self) -> LabelSet:
        return self._label_set

    @property
    def uses_depth(self) -> bool:
        """Whether the network also takes a depth image."""
        return bool(getattr(self._model, "uses_depth", False))

    # ------------------------------------------------------------------ inference
    def logits(self, rgbs: Sequence[np.ndarray], depths: Sequence[np.ndarray] | None = None) -> np.ndarray:
        """(N, K, h', w') float32 network output for a batch of RGB images (and depth images in metres, for a
        network that uses depth), at network resolution."""
        x = self.net_input.batch(rgbs)
        inputs = {"image": x}
        if self.uses_depth:
            if depths is None:
                raise ConfigError(f"{self.name}: this network needs depth images")
            inputs["depth"] = self.net_input.depth_batch(depths, rgbs[0].shape[:2])
        if self.backend == "onnx":
            n = x.shape[0]
            if n < self.batch_size:  # a short last batch runs padded: one graph per run, not one more export
                inputs = {name: np.concatenate([v, np.repeat(v[:1], self.batch_size - n, axis=0)])
                          for name, v in inputs.items()}
            shape = inputs["image"].shape
            if shape not in self._sessions:
                self._sessions[shape] = _onnx_session(self._model, shape, self._cache_dir, self._cache_key,
                                                      self._threads, with_depth=self.uses_depth)
            return self._sessions[shape].run(None, inputs)[0][:n]
        with self._torch.inference_mode():
            return self._model(*(self._torch.from_numpy(v) for v in inputs.values())).numpy()

    def _top_classes(self, rgbs: Sequence[np.ndarray], k: int, depths: Sequence[np.ndarray] | None = None,
                     names: Sequence[str] | None = None) -> list[tuple[np.ndarray, np.ndarray]]:
        """Per image, (labels, probs) of its ``k`` most likely classes at the image's own resolution.

        Softmax runs on the network's output grid; probabilities are then sampled bilinearly at each image pixel
        through the exact resize geometry (image -> network input -> logit grid), in one numba pass. A network
        output holding NaN or infinity stops here (ConfigError naming the image: ``names``, else its batch index).
        """
        from semmap.perception._resample_kernels import resample_topk, sampling_map, softmax_channels_last

        h, w = rgbs[0].shape[:2]
        if any(r.shape[:2] != (h, w) for r in rgbs):
            raise ConfigError("all images of a batch must have the same size")
        logits = np.ascontiguousarray(self.logits(rgbs, depths), dtype=np.float32)
        if logits.ndim != 4:
            raise ConfigError(f"{self.name}: network output has shape {logits.shape}, expected (N, K, h, w)")
        if logits.shape[1] != len(self._label_set):
            raise ConfigError(f"{self.name}: network predicts {logits.shape[1]} classes but its label set has "
                              f"{len(self._label_set)}")
        _check_finite_logits(logits, self.name, names)
        if self.temperature != 1.0:  # temperature scaling (perception/calibration.py): softmax(logits / T)
            logits *= np.float32(1.0 / self.temperature)
        in_w, in_h = self.net_input.size_for(w, h)
        align = bool(getattr(self._model, "logits_align_corners", False))
        sy, oy = sampling_map(h, in_h, logits.shape[2], align)
        sx, ox = sampling_map(w, in_w, logits.shape[3], align)
        return [resample_topk(softmax_channels_last(lg), h, w, sy, oy, sx, ox, k, EMPTY_LABEL) for lg in logits]

    def probabilities(self, rgb: np.ndarray, depth: np.ndarray | None = None) -> np.ndarray:
        """(H, W, K) float16 class probabilities of one image (``depth`` in metres, for RGB-D networks)."""
        return self.probabilities_batch([rgb], None if depth is None else [depth])[0]

    def probabilities_batch(self, rgbs: Sequence[np.ndarray],
                            depths: Sequence[np.ndarray] | None = None) -> np.ndarray:
        """(N, H, W, K) float16 class probabilities of a batch of equally sized images."""
        n_classes = len(self._label_set)
        out = np.zeros((len(rgbs), *rgbs[0].shape[:2], n_classes), np.float16)
        for i, (labels, probs) in enumerate(self._top_classes(rgbs, n_classes, depths)):
            np.put_along_axis(out[i], labels.astype(np.intp), probs.astype(np.float16), axis=-1)
        return out

    def predict(self, rgb: np.ndarray, depth: np.ndarray | None = None) -> TopKProbs:
        """(H, W, k) top-k class distribution of one image (``depth`` in metres, for RGB-D networks)."""
        return self.predict_batch([rgb], None if depth is None else [depth])[0]

    def predict_batch(self, rgbs: Sequence[np.ndarray], depths: Sequence[np.ndarray] | None = None,
                      names: Sequence[str] | None = None) -> list[TopKProbs]:
        """Top-k class distributions of images, run through the network ``batch_size`` at a time (``names`` name
        the images in errors)."""
        out: list[TopKProbs] = []
        names = list(names) if names is not None else [f"image {i}" for i in range(len(rgbs))]
        for start in range(0, len(rgbs), self.batch_size):
            stop = start + self.batch_size
            out.extend(TopKProbs(labels, probs) for labels, probs in
                       self._top_classes(rgbs[start:stop], self.k, None if depths is None else depths[start:stop],
                                         names[start:stop]))
        return out

    def prepare(self, frame: Frame) -> float:
        """Export or open the ONNX graph (or let PyTorch pick its kernels) by segmenting ``frame`` once, so that the
        first frame of a run costs what the others do; returns the seconds it took."""
        t = time.perf_counter()
        self.segment(frame)
        return time.perf_counter() - t

    def segment(self, frame: Frame) -> TopKProbs:
        """Class distribution on the frame's depth grid; a frame that keeps its colour camera's own image
        (``raw_color``) is segmented on that whole view and the result carried onto the depth grid (RGB-D
        networks take the colour registered onto the depth image, with the depth)."""
        return self.segment_batch([frame])[0]

    def segment_batch(self, frames: Sequence[Frame]) -> list[TopKProbs]:
        names = [f"frame {f.name or f.index}" for f in frames]
        if self.uses_depth:
            return self.predict_batch([f.rgb for f in frames], [f.depth for f in frames], names)
        tops = self.predict_batch([f.rgb if f.raw_color is None else f.raw_color.image for f in frames], names=names)
        return [TopKProbs(*onto_depth_grid(f, t.labels, t.probs)) for f, t in zip(frames, tops, strict=True)]


def _check_finite_logits(logits: np.ndarray, network: str, names: Sequence[str] | None) -> None:
    """ConfigError naming the first image whose network output holds NaN or infinity (a damaged network would
    otherwise map every voxel as unknown without a word)."""
    finite = np.isfinite(logits).reshape(len(logits), -1).all(axis=1)
    if finite.all():
        return
    i = int(np.argmin(finite))
    what = names[i] if names is not None and i < len(names) else f"image {i} of the batch"
    raise ConfigError(f"{network}: the network output NaN or infinite scores on {what}; its weights or its input "
                      f"are broken (the run stops here)")


def export_onnx(model, path: Path, shape: tuple[int, ...], *, with_depth: bool = False) -> Path:
    """Export ``model`` to ONNX at input ``shape`` (N, 3, H, W) (inputs ``image`` and, ``with_depth``,
    ``depth`` (N, 1, H, W); output ``logits``), written atomically."""
    import torch

    n, _, h, w = shape
    args = (torch.zeros(n, 3, h, w),) + ((torch.ones(n, 1, h, w),) if with_depth else ())
    names = ["image", "depth"] if with_depth else ["image"]
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f"{path.name}.{os.getpid()}.tmp")  # (two processes may export the same graph at once)
    with torch.inference_mode(), warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)  # the TorchScript exporter needs no onnxscript
        # one graph per input shape is the intent: the tracer's notes on shapes read as constants are noise
        warnings.simplefilter("ignore", torch.jit.TracerWarning)
        torch.onnx.export(model, args, str(tmp), input_names=names, output_names=["logits"], opset_version=17,
                          dynamo=False)
    tmp.replace(path)
    return path


def onnx_cache_dir() -> Path:
    """Where exported ONNX graphs are kept: ``$SEMMAP_CACHE_DIR/onnx`` (default ``~/.cache/semmap/onnx``)."""
    return Path(os.environ.get("SEMMAP_CACHE_DIR", Path.home() / ".cache" / "semmap")) / "onnx"


def _source_digest(cls: type) -> str:
    """Hash of the source file that defines ``cls`` (empty when it has none)."""
    import sys

    path = getattr(sys.modules.get(cls.__module__), "__file__", None)
    return hashlib.sha1(Path(path).read_bytes()).hexdigest()[:12] if path else ""


def _onnx_session(model, shape: tuple[int, ...], cache_dir: Path | None, cache_key: str, threads: int | None,
                  with_depth: bool = False):
    """An ONNX Runtime session for ``model`` at input ``shape`` (N, 3, H, W), exported once to ``cache_dir``
    (keyed by the weights and the shape)."""
    import onnxruntime as ort
    import torch

    n, _, h, w = shape
    root = cache_dir or onnx_cache_dir()
    code = _source_digest(type(model))  # an edited model is exported again, not served from an old graph
    key = hashlib.sha1(f"{cache_key}|{n}x{w}x{h}|{torch.__version__}|{code}".encode()).hexdigest()[:16]
    path = root / f"{type(model).__name__.lower()}-{key}.onnx"
    if not path.is_file():
        log.info("exporting %s to ONNX (%s), once", type(model).__name__, path)
        export_onnx(model, path, shape, with_depth=with_depth)
    options = ort.SessionOptions()
    if threads is not None:
        options.intra_op_num_threads = int(threads)
    options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    return ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
