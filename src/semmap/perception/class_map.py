"""A model's own classes as a label set, and JSON class mappings that fold them into the map's label set.

A user's network (``--segmenter onnx:...`` / ``hf:...``) predicts its own classes (ADE20K-150, NYU-40, COCO, ...).
Without a mapping its classes become the map's label set, behind an ``unknown`` class 0 where the model's first
class is a real one (semmap's id 0 is always void). With ``--class-map FILE`` every model class is sent to one
label of the target set (semmap's indoor classes by default) and the probabilities of classes sent to the same
label are added, before the top-k is taken; classes the file does not name go to ``unknown``.

Mapping file (JSON)::

    {"labels": "semmap",                    # target: "semmap" (the simulator's classes), "nyu40", or a list of
                                            # names whose first is the void class
     "map": {"floor": "floor", "rug": "floor", "7": "table", "sky": null}}

Keys name a model class by name (case and surrounding spaces ignored; a model's ``"pot, flowerpot"`` is also
``pot``) or by id; values are a target label name, or null (the class is void). An optional ``"classes"`` lists
the model classes the file was written for (documentation, and the classes of the tests' tiny models).
Shipped examples: :func:`shipped_class_maps` (``class_maps/`` beside this file).
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from semmap.errors import ConfigError
from semmap.files.safe import read_text_limited
from semmap.labels import INDOOR_LABELS, nyu40_labels
from semmap.types import LabelSet, distinct_colors

#: Names a model may give its first class when it means "nothing / not a class" (kept as semmap's void id 0).
VOID_NAMES = frozenset({"unknown", "void", "background", "unlabeled", "unlabelled", "other", "others", "none",
                        "__background__"})
#: Built-in target label sets a mapping file may name in ``"labels"``.
TARGETS = {"semmap": lambda: INDOOR_LABELS, "nyu40": nyu40_labels}
#: The mapping files shipped with semmap.
CLASS_MAP_DIR = Path(__file__).resolve().parent / "class_maps"


def shipped_class_maps() -> dict[str, Path]:
    """The example mapping files shipped with semmap, by stem (``ade20k-150``, ``nyu40``, ``coco-panoptic-133``)."""
    return {p.stem: p for p in sorted(CLASS_MAP_DIR.glob("*.json"))}


def _key(name: str) -> str:
    return " ".join(str(name).split()).lower()


def model_label_set(names: Sequence[str]) -> tuple[LabelSet, int]:
    """The label set of a model's own classes and the id offset of its class 0: 0 when the model's first class is
    void-like (``background``, ``unknown``, ...), else 1 (an ``unknown`` class 0 is put in front). Classes that
    share a name with semmap's take its colour."""
    names = tuple(str(n).strip() for n in names)
    offset = 0 if names and _key(names[0]) in VOID_NAMES else 1
    full = (("unknown",) if offset else ()) + names
    colors = distinct_colors(len(full))
    own = {_key(n): i for i, n in enumerate(INDOOR_LABELS.names)}
    for i, name in enumerate(full):
        if i > 0 and _key(name) in own:
            colors[i] = INDOOR_LABELS.colors[own[_key(name)]]
    return LabelSet(full, colors), offset


@dataclass(frozen=True)
class ClassFold:
    """How a model's K classes become the map's: ``matrix`` (K, K') of 0/1 (each row one target id), the target
    ``label_set``, and where it came from (``source``: the mapping file, or the model's own names)."""

    matrix: np.ndarray
    label_set: LabelSet
    source: str

    def apply(self, probs: np.ndarray) -> np.ndarray:
        """(h, w, K') float32 target probabilities from (h, w, K) model probabilities (summed per target)."""
        h, w, k = probs.shape
        return np.ascontiguousarray((probs.reshape(-1, k) @ self.matrix).reshape(h, w, -1), dtype=np.float32)


def own_classes(names: Sequence[str], where: str) -> ClassFold:
    """The identity fold onto the model's own label set (shifted by one when its class 0 is a real class)."""
    label_set, offset = model_label_set(names)
    matrix = np.zeros((len(names), len(label_set)), np.float32)
    matrix[np.arange(len(names)), np.arange(len(names)) + offset] = 1.0
    return ClassFold(matrix, label_set, where)


def _target(value: object, path: Path) -> LabelSet:
    """The target label set a mapping file names in ``"labels"`` (default semmap's)."""
    if value is None:
        return INDOOR_LABELS
    if isinstance(value, str):
        if value not in TARGETS:
            raise ConfigError(f"{path}: field 'labels' must be {' or '.join(map(repr, TARGETS))} or a list of "
                              f"names, got {value!r}")
        return TARGETS[value]()
    if (not isinstance(value, list) or len(value) < 2 or not all(isinstance(v, str) and v.strip() for v in value)
            or len({_key(v) for v in value}) != len(value)):
        raise ConfigError(f"{path}: field 'labels' must list at least two distinct class names (the first is void)")
    return LabelSet(tuple(v.strip() for v in value), distinct_colors(len(value)))


def read_json_object(path: Path, what: str) -> dict:
    """A JSON object from ``path``, or a ConfigError naming the file."""
    text = read_text_limited(path, what=what, error=lambda reason: ConfigError(f"{path}: {reason}"))
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ConfigError(f"{path}: not valid JSON ({exc.msg}, line {exc.lineno})") from None
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: the {what} must be a JSON object, got {type(data).__name__}")
    return data


def resolve_class_map(text: str | Path) -> Path:
    """A ``--class-map`` argument as a file: the path itself, or the name of a shipped mapping (``ade20k-150``)."""
    path = Path(text)
    if path.exists():
        return path
    shipped = shipped_class_maps()
    if str(text) in shipped:
        return shipped[str(text)]
    raise ConfigError(f"--class-map: {path} does not exist (shipped mappings: {', '.join(shipped)})")


def read_class_map(path: str | Path, model_classes: Sequence[str]) -> ClassFold:
    """The fold a mapping file describes for a model with classes ``model_classes`` (ConfigError naming the file
    and the key on a class the model does not have or a label the target set does not have)."""
    path = resolve_class_map(path)
    data = read_json_object(path, "class mapping")
    unknown = sorted(set(data) - {"labels", "map", "classes", "note"})
    if unknown:
        raise ConfigError(f"{path}: unknown field {unknown[0]!r}; a class mapping has 'labels', 'map', 'classes' "
                          "and 'note'")
    target = _target(data.get("labels"), path)
    mapping = data.get("map")
    if not isinstance(mapping, dict) or not mapping:
        raise ConfigError(f"{path}: field 'map' must be a non-empty object of model class -> label name")
    by_name = {}  # a model's "pot, flowerpot" is found as "pot" too
    for i, n in reversed(list(enumerate(model_classes))):
        by_name[_key(str(n).split(",")[0])] = i
    by_name.update({_key(n): i for i, n in enumerate(model_classes)})
    target_ids = {_key(n): i for i, n in enumerate(target.names)}
    matrix = np.zeros((len(model_classes), len(target)), np.float32)
    matrix[:, 0] = 1.0  # classes the file does not name are void
    for key, label in mapping.items():
        k = _key(key)
        cls = by_name.get(k, int(k) if k.isdigit() and int(k) < len(model_classes) else None)
        if cls is None:
            raise ConfigError(f"{path}: map key {key!r} is not one of the model's {len(model_classes)} classes "
                              f"({', '.join(model_classes[:6])}, ...)")
        if label is not None and (not isinstance(label, str) or _key(label) not in target_ids):
            raise ConfigError(f"{path}: map[{key!r}] = {label!r} is not a label of the target set "
                              f"({', '.join(target.names[:8])}, ...)")
        matrix[cls] = 0.0
        matrix[cls, 0 if label is None else target_ids[_key(label)]] = 1.0
    return ClassFold(matrix, target, str(path))
