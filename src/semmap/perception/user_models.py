"""The segmenter a user already has: any ONNX semantic-segmentation model described by a small JSON sidecar
(``--segmenter onnx:MODEL.onnx``), and the common frame -> top-k path of it and of ``transformers`` models
(:mod:`semmap.perception.hf_models`).

Sidecar (``MODEL.json`` beside the model, or ``--segmenter-config FILE``)::

    {"input":  {"size": [512, 512],          # network input (width, height); or "short_side": 384
                "layout": "NCHW",            # or "NHWC"
                "channels": "RGB",           # or "BGR"
                "scale": 0.00392156862745098,  # pixel * scale, then (- mean) / std per channel
                "mean": [0.485, 0.456, 0.406], "std": [0.229, 0.224, 0.225],
                "name": "pixel_values"},     # optional: the model's single input is used
     "output": {"kind": "logits",            # or "probabilities"
                "layout": "NCHW",            # or "NHWC"
                "name": "logits",            # optional: the first output
                "align_corners": false},     # whether the output grid spans the input corner to corner
     "labels": ["wall", "building", ...]}    # one name per output channel (or {"0": "wall", ...})

Every field is checked against the model when it is opened (rank, channel counts, fixed sizes), with one line
naming the file and the field.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from semmap.errors import ConfigError
from semmap.files.safe import path_kind
from semmap.geometry import onto_depth_grid
from semmap.limits import check_network_input
from semmap.perception.class_map import ClassFold, own_classes, read_class_map, read_json_object
from semmap.perception.network import NetworkInput
from semmap.types import EMPTY_LABEL, Frame, LabelSet, TopKProbs

LAYOUTS = ("NCHW", "NHWC")
CHANNEL_ORDERS = ("RGB", "BGR")
OUTPUT_KINDS = ("logits", "probabilities")
_FIELDS = {"input": {"size", "short_side", "multiple", "layout", "channels", "scale", "mean", "std", "name"},
           "output": {"kind", "layout", "name", "align_corners"}, "labels": None, "note": None}


@dataclass(frozen=True)
class ModelOutput:
    """A batch of a model's class scores: (N, K, h, w) float32, as ``logits`` or ``probabilities``, on a grid
    that spans the network input with half-pixel centres or (``align_corners``) corner to corner."""

    scores: np.ndarray
    kind: str = "logits"
    align_corners: bool = False


class ModelSegmenter:
    """:class:`~semmap.perception.base.Segmenter` around a function from a network-input batch to class scores:
    probabilities on the model's grid, folded into the map's classes (:class:`ClassFold`), sampled bilinearly at
    each image pixel, top-k, carried onto the depth grid."""

    def __init__(self, name: str, run: Callable[[Sequence[np.ndarray]], ModelOutput], net_input: NetworkInput,
                 fold: ClassFold, *, k: int = 3, batch_size: int = 1, what: str = ""):
        if k < 1:
            raise ConfigError(f"k must be at least 1, got {k}")
        _check_size(net_input, batch_size, f"{what or name} network input")
        self.name, self._run, self.net_input, self.fold = name, run, net_input, fold
        self.k, self.batch_size, self.what = k, max(1, int(batch_size)), what or name

    @property
    def label_set(self) -> LabelSet:
        return self.fold.label_set

    def _probabilities(self, out: ModelOutput, names: Sequence[str]) -> list[np.ndarray]:
        """Per image, (h, w, K') float32 probabilities over the map's classes on the model's grid."""
        from semmap.perception._resample_kernels import softmax_channels_last

        scores = out.scores
        if scores.ndim != 4 or scores.shape[1] != self.fold.matrix.shape[0]:
            raise ConfigError(f"{self.what}: the model output has shape {scores.shape}, expected (N, "
                              f"{self.fold.matrix.shape[0]}, h, w)")
        probs = []
        for s, name in zip(scores, names, strict=True):
            if not np.isfinite(s).all():
                raise ConfigError(f"{self.what}: the model output NaN or infinite scores on {name}")
            if out.kind == "logits":
                p = softmax_channels_last(np.ascontiguousarray(s, dtype=np.float32))
            else:
                p = np.clip(s.transpose(1, 2, 0), 0.0, None)
                p = p / np.maximum(p.sum(-1, keepdims=True), 1e-12)
            probs.append(self.fold.apply(p))
        return probs

    def predict_batch(self, rgbs: Sequence[np.ndarray], names: Sequence[str] | None = None) -> list[TopKProbs]:
        """Top-k class distributions of equally sized RGB images, ``batch_size`` at a time."""
        from semmap.perception._resample_kernels import resample_topk, sampling_map

        names = list(names) if names is not None else [f"image {i}" for i in range(len(rgbs))]
        tops: list[TopKProbs] = []
        for start in range(0, len(rgbs), self.batch_size):
            chunk = rgbs[start:start + self.batch_size]
            h, w = chunk[0].shape[:2]
            in_w, in_h = self.net_input.size_for(w, h)
            out = self._run(chunk)
            for p in self._probabilities(out, names[start:start + len(chunk)]):
                sy, oy = sampling_map(h, in_h, p.shape[0], out.align_corners)
                sx, ox = sampling_map(w, in_w, p.shape[1], out.align_corners)
                tops.append(TopKProbs(*resample_topk(p, h, w, sy, oy, sx, ox, self.k, EMPTY_LABEL)))
        return tops

    def predict(self, rgb: np.ndarray) -> TopKProbs:
        """(H, W, k) top-k class distribution of one RGB image."""
        return self.predict_batch([rgb])[0]

    def segment_batch(self, frames: Sequence[Frame]) -> list[TopKProbs]:
        """Class distributions on the frames' depth grids (a frame's own colour camera image where it keeps one)."""
        rgbs = [f.rgb if f.raw_color is None else f.raw_color.image for f in frames]
        tops = self.predict_batch(rgbs, [f"frame {f.name or f.index}" for f in frames])
        return [TopKProbs(*onto_depth_grid(f, t.labels, t.probs)) for f, t in zip(frames, tops, strict=True)]

    def segment(self, frame: Frame) -> TopKProbs:
        return self.segment_batch([frame])[0]

    def prepare(self, frame: Frame) -> float:
        """Run the model once on ``frame`` (kernel selection, lazy allocations); returns the seconds."""
        t = time.perf_counter()
        self.segment(frame)
        return time.perf_counter() - t


def _check_size(net_input: NetworkInput, batch_size: int, option: str) -> None:
    """The network input's sides and a batch's memory within semmap's limits (a 4:3 image for a short side)."""
    size = net_input.size or (net_input.short_side * 4 // 3, net_input.short_side)
    check_network_input(int(size[0]), int(size[1]), max(1, int(batch_size)), option=option)


def class_fold(names: Sequence[str], class_map: Path | None, where: str) -> ClassFold:
    """The model's classes folded by ``class_map`` (a file or shipped name), or kept as they are."""
    return own_classes(names, where) if class_map is None else read_class_map(class_map, names)


# --------------------------------------------------------------------------------------------------
# The ONNX sidecar
# --------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Sidecar:
    """A checked sidecar: how to feed the model and read its output, and its class names."""

    path: Path
    net_input: NetworkInput | None  #: None: the model's own fixed input size (filled in when it is opened)
    input_layout: str
    bgr: bool
    scale: float
    mean: tuple[float, float, float]
    std: tuple[float, float, float]
    input_name: str | None
    output_kind: str
    output_layout: str
    output_name: str | None
    align_corners: bool
    labels: tuple[str, ...]
    normalises: bool = False  #: the sidecar sets scale, mean or std


def sidecar_path(model: Path, config: Path | None) -> Path:
    """The sidecar of ``model``: ``config`` when given, else ``MODEL.json`` beside it (ConfigError when absent)."""
    path = config if config is not None else model.with_suffix(".json")
    if not path.is_file():
        how = "--segmenter-config" if config is not None else f"no sidecar {path} beside the model (or pass " \
                                                               "--segmenter-config FILE)"
        raise ConfigError(f"{path}: {path_kind(path)}; the ONNX segmenter needs a JSON sidecar ({how}; see "
                          f"docs/segmenters.md)" if config is not None else f"{model}: {how}; it says the input "
                          "size, layout, normalisation, output layout and label names (docs/segmenters.md)")
    return path


def _choice(section: dict, field: str, choices: tuple[str, ...], default: str, path: Path, where: str) -> str:
    value = section.get(field, default)
    if value not in choices:
        raise ConfigError(f"{path}: {where}.{field} must be {' or '.join(choices)}, got {value!r}")
    return value


def _number(section: dict, field: str, default: float, path: Path, where: str, *, positive: bool = False) -> float:
    value = section.get(field, default)
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value) or (
            positive and value <= 0):
        raise ConfigError(f"{path}: {where}.{field} must be a finite {'positive ' if positive else ''}number, "
                          f"got {value!r}")
    return float(value)


def _triple(section: dict, field: str, default: float, path: Path, *, positive: bool = False) -> tuple:
    value = section.get(field, [default] * 3)
    if isinstance(value, int | float) and not isinstance(value, bool):
        value = [value] * 3
    if not isinstance(value, list) or len(value) != 3:
        raise ConfigError(f"{path}: input.{field} must be one number or three (one per channel), got {value!r}")
    return tuple(_number({field: v}, field, default, path, "input", positive=positive) for v in value)


def _labels(value: object, path: Path) -> tuple[str, ...]:
    """Class names from a list, or an ``{"0": name, ...}`` object covering ids 0..K-1."""
    if isinstance(value, dict):
        try:
            ids = {int(k): v for k, v in value.items()}
        except ValueError:
            raise ConfigError(f"{path}: labels as an object must map class ids 0..K-1 to names") from None
        if sorted(ids) != list(range(len(ids))):
            raise ConfigError(f"{path}: labels must name every class id 0..{len(ids) - 1} once")
        value = [ids[i] for i in range(len(ids))]
    if not isinstance(value, list) or len(value) < 1 or not all(isinstance(v, str) and v.strip() for v in value):
        raise ConfigError(f"{path}: labels must be a non-empty list of class names, one per output channel")
    if len({v.strip().lower() for v in value}) != len(value):
        raise ConfigError(f"{path}: labels must not name a class twice")
    return tuple(v.strip() for v in value)


def _sidecar_input(section: dict, path: Path) -> NetworkInput | None:
    """The network input size the sidecar asks for (None: the model's own)."""
    if "size" in section:
        size = section["size"]
        if (not isinstance(size, list) or len(size) != 2
                or not all(isinstance(v, int) and not isinstance(v, bool) for v in size)):
            raise ConfigError(f"{path}: input.size must be [width, height] in pixels, got {size!r}")
        return NetworkInput(size=(size[0], size[1]), short_side=None)
    if "short_side" in section:
        side = section["short_side"]
        multiple = section.get("multiple", 32)
        if not isinstance(side, int) or isinstance(side, bool) or not isinstance(multiple, int) or multiple < 1:
            raise ConfigError(f"{path}: input.short_side and input.multiple must be whole numbers of pixels")
        return NetworkInput(short_side=side, multiple=multiple)
    return None


def read_sidecar(path: Path) -> Sidecar:
    """The sidecar at ``path``, checked field by field (unknown fields are refused: a typo would be ignored)."""
    data = read_json_object(path, "ONNX sidecar")
    for name, value in data.items():
        if name not in _FIELDS:
            raise ConfigError(f"{path}: unknown field {name!r}; a sidecar has {', '.join(_FIELDS)}")
        allowed = _FIELDS[name]
        if allowed is not None:
            if not isinstance(value, dict):
                raise ConfigError(f"{path}: {name} must be an object")
            extra = sorted(set(value) - allowed)
            if extra:
                raise ConfigError(f"{path}: unknown field {name}.{extra[0]}; known: {', '.join(sorted(allowed))}")
    if "labels" not in data:
        raise ConfigError(f"{path}: missing field 'labels' (one class name per output channel)")
    inp, out = data.get("input", {}), data.get("output", {})
    try:
        net_input = _sidecar_input(inp, path)
    except ConfigError as exc:
        raise ConfigError(f"{path}: input: {exc}") from None
    for section, where in ((inp, "input"), (out, "output")):
        if "name" in section and not isinstance(section["name"], str):
            raise ConfigError(f"{path}: {where}.name must be a string")
    if not isinstance(out.get("align_corners", False), bool):
        raise ConfigError(f"{path}: output.align_corners must be true or false")
    return Sidecar(path, net_input, _choice(inp, "layout", LAYOUTS, "NCHW", path, "input"),
                   _choice(inp, "channels", CHANNEL_ORDERS, "RGB", path, "input") == "BGR",
                   _number(inp, "scale", 1.0 / 255.0, path, "input", positive=True),
                   _triple(inp, "mean", 0.0, path), _triple(inp, "std", 1.0, path, positive=True), inp.get("name"),
                   _choice(out, "kind", OUTPUT_KINDS, "logits", path, "output"),
                   _choice(out, "layout", LAYOUTS, "NCHW", path, "output"), out.get("name"),
                   bool(out.get("align_corners", False)), _labels(data["labels"], path),
                   normalises=bool({"scale", "mean", "std"} & set(inp)))



# --------------------------------------------------------------------------------------------------
# The ONNX model
# --------------------------------------------------------------------------------------------------
_INPUT_TYPES = {"tensor(float)": np.float32, "tensor(float16)": np.float16, "tensor(uint8)": np.uint8}


def _pick(items: list, name: str | None, what: str, model: Path, sidecar: Path, field: str):
    """The model input or output named ``name`` (or the only input / first output)."""
    names = [i.name for i in items]
    if name is not None:
        if name not in names:
            raise ConfigError(f"{sidecar}: {field} {name!r} is not one of {model}'s {what}s ({', '.join(names)})")
        return items[names.index(name)]
    if what == "input" and len(items) != 1:
        raise ConfigError(f"{model}: the model has {len(items)} inputs ({', '.join(names)}); name the image input "
                          f"in {sidecar}: {field}")
    return items[0]


def _fixed(dim: object) -> int | None:
    return dim if isinstance(dim, int) and dim > 0 else None


def _model_input(inp, side: Sidecar, model: Path, input_size: tuple[int, int] | int | None) -> NetworkInput:
    """The network input for the model's image input ``inp``: rank, channels and fixed sizes checked against the
    sidecar (and ``--input-size``)."""
    shape, s = list(inp.shape or []), side.path
    if len(shape) != 4:
        raise ConfigError(f"{model}: input {inp.name!r} has rank {len(shape)} (shape {shape}); semmap feeds a batch "
                          f"of colour images of rank 4 ({s}: input.layout {side.input_layout})")
    c_axis, hw = (1, (2, 3)) if side.input_layout == "NCHW" else (3, (1, 2))
    if _fixed(shape[c_axis]) not in (None, 3):
        raise ConfigError(f"{model}: input {inp.name!r} has {shape[c_axis]} channels on the channel axis of "
                          f"{side.input_layout} (shape {shape}); expected 3 ({s}: input.layout)")
    if inp.type not in _INPUT_TYPES:
        raise ConfigError(f"{model}: input {inp.name!r} is {inp.type}; semmap feeds float, float16 or uint8 images")
    if np.dtype(_INPUT_TYPES[inp.type]) == np.uint8 and side.normalises:
        raise ConfigError(f"{s}: input.scale/mean/std: {model}'s input {inp.name!r} takes uint8 pixels as they are")
    h, w = _fixed(shape[hw[0]]), _fixed(shape[hw[1]])
    wanted = side.net_input
    if input_size is not None:
        wanted = (NetworkInput(short_side=input_size, multiple=32) if isinstance(input_size, int)
                  else NetworkInput(size=tuple(input_size), short_side=None))
    if h is not None and w is not None:
        if wanted is not None and (wanted.size is None or tuple(wanted.size) != (w, h)):
            got = f"{wanted.size[0]}x{wanted.size[1]}" if wanted.size else f"short side {wanted.short_side}"
            where = "--input-size" if input_size is not None else f"{s}: input.size"
            raise ConfigError(f"{where} is {got}, but {model}'s input {inp.name!r} is fixed at {w}x{h}")
        wanted = NetworkInput(size=(w, h), short_side=None)
    if wanted is None:
        raise ConfigError(f"{s}: input.size (or input.short_side) is needed: {model}'s input {inp.name!r} has no "
                          f"fixed height and width (shape {shape})")
    k = side.scale * 255.0  # NetworkInput normalises pixel / 255: the same numbers as (pixel * scale - mean) / std
    return NetworkInput(size=wanted.size, short_side=wanted.short_side, multiple=wanted.multiple,
                        mean=tuple(m / k for m in side.mean), std=tuple(v / k for v in side.std))


def _check_output(out, side: Sidecar, model: Path) -> None:
    """The output's rank and class count (where the model fixes them) against the sidecar's labels."""
    shape, s = list(out.shape or []), side.path
    if len(shape) != 4:
        raise ConfigError(f"{model}: output {out.name!r} has rank {len(shape)} (shape {shape}); expected class "
                          f"scores of rank 4 ({s}: output.layout {side.output_layout})")
    c = _fixed(shape[1 if side.output_layout == "NCHW" else 3])
    if c is not None and c != len(side.labels):
        raise ConfigError(f"{model}: output {out.name!r} has {c} channels ({side.output_layout}, shape {shape}) but "
                          f"{s}: labels names {len(side.labels)} classes")


def open_onnx_session(model: Path, threads: int | None):
    """An ONNX Runtime CPU session for the user's model (ConfigError naming the file when it cannot be opened)."""
    import onnxruntime as ort

    if not model.is_file():
        raise ConfigError(f"{model}: {path_kind(model)}; --segmenter onnx:MODEL names an ONNX model file")
    options = ort.SessionOptions()
    options.log_severity_level = 3
    if threads is not None:
        options.intra_op_num_threads = int(threads)
    try:
        return ort.InferenceSession(str(model), options, providers=["CPUExecutionProvider"])
    except Exception as exc:  # onnxruntime raises its own exception types (InvalidProtobuf, Fail, ...)
        first = str(exc).strip().splitlines()[0][:200] if str(exc).strip() else type(exc).__name__
        raise ConfigError(f"{model}: ONNX Runtime cannot open it as a model ({first})") from None


def onnx_segmenter(name: str, model: Path, *, config: Path | None = None, class_map: Path | None = None,
                   k: int = 3, batch_size: int = 1, threads: int | None = None,
                   input_size: tuple[int, int] | int | None = None) -> ModelSegmenter:
    """A segmenter running the user's ONNX ``model`` as its sidecar (``config``, else ``MODEL.json``) says."""
    model = Path(model)
    session = open_onnx_session(model, threads)  # (first: a missing or foreign file is named as the model)
    side = read_sidecar(sidecar_path(model, config))
    inp = _pick(session.get_inputs(), side.input_name, "input", model, side.path, "input.name")
    out = _pick(session.get_outputs(), side.output_name, "output", model, side.path, "output.name")
    net_input = _model_input(inp, side, model, input_size)
    _check_output(out, side, model)
    _check_size(net_input, batch_size, "--input-size" if input_size is not None else f"{side.path}: input.size")
    dtype = np.dtype(_INPUT_TYPES[inp.type])
    fixed_batch = _fixed(inp.shape[0])
    batch = fixed_batch or batch_size

    def run(rgbs: Sequence[np.ndarray]) -> ModelOutput:
        x = net_input.batch(rgbs)  # (N, 3, h, w) float32, normalised as the sidecar says
        if dtype == np.uint8:
            x = np.clip(np.rint(x * 255.0), 0, 255)  # the sidecar's default normalisation is pixel / 255
        if side.bgr:
            x = x[:, ::-1]
        if side.input_layout == "NHWC":
            x = x.transpose(0, 2, 3, 1)
        n = len(rgbs)
        if fixed_batch is not None and n < fixed_batch:
            x = np.concatenate([x, np.repeat(x[:1], fixed_batch - n, axis=0)])
        scores = np.asarray(session.run([out.name], {inp.name: np.ascontiguousarray(x, dtype=dtype)})[0])[:n]
        if scores.ndim == 4 and side.output_layout == "NHWC":
            scores = scores.transpose(0, 3, 1, 2)
        if scores.ndim != 4 or scores.shape[1] != len(side.labels):
            raise ConfigError(f"{model}: output {out.name!r} has shape {list(scores.shape)} ({side.output_layout}) "
                              f"but {side.path}: labels names {len(side.labels)} classes")
        return ModelOutput(np.asarray(scores, np.float32), side.output_kind, side.align_corners)

    fold = class_fold(side.labels, class_map, str(side.path))
    return ModelSegmenter(name, run, net_input, fold, k=k, batch_size=batch, what=str(model))
