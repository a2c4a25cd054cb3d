"""A run's in-memory state (maps, counters, poses so far) written to one file and read back exactly, for
checkpoints: ``save_state(path, obj)`` / ``load_state(path)``.

The object graph is walked: numpy arrays go into an uncompressed ``.npz`` as they are, everything else into a JSON
description inside it: numbers, strings, lists, tuples, dicts with string keys, Enums, and instances of semmap's
own classes (their ``__dict__``). Reading back creates those instances with ``cls.__new__`` and fills their
``__dict__``: no constructor and no other code runs, and only classes defined in ``semmap`` are accepted, so a
damaged or hostile checkpoint is a :class:`FormatError`, never code execution (unlike pickle).
"""

from __future__ import annotations

import enum
import importlib
import json
from pathlib import Path

import numpy as np

from semmap.errors import FormatError
from semmap.files.atomic import write_atomic

FORMAT = "semmap-state"
VERSION = 1
_TAG = "__semmap__"


def _encode(obj, arrays: list[np.ndarray]):
    """JSON-able description of ``obj``; arrays appended to ``arrays`` and referred to by index."""
    if obj is None or isinstance(obj, bool | int | float | str):
        if isinstance(obj, float) and not np.isfinite(obj):
            return {_TAG: "float", "value": repr(obj)}
        return obj
    if isinstance(obj, np.ndarray | np.generic):
        arrays.append(np.asarray(obj))
        return {_TAG: "array", "index": len(arrays) - 1, "scalar": isinstance(obj, np.generic)}
    if isinstance(obj, enum.Enum):
        return {_TAG: "enum", "class": _name_of(type(obj)), "value": _encode(obj.value, arrays)}
    if isinstance(obj, list | tuple):
        return {_TAG: type(obj).__name__, "items": [_encode(v, arrays) for v in obj]}
    if isinstance(obj, dict):
        if not all(isinstance(k, str) for k in obj):
            raise FormatError(f"cannot save a dict with non-string keys ({next(iter(obj))!r}) in a checkpoint")
        return {_TAG: "dict", "items": {k: _encode(v, arrays) for k, v in obj.items()}}
    cls = type(obj)
    if cls.__module__.split(".")[0] == "semmap" and hasattr(obj, "__dict__"):
        return {_TAG: "object", "class": _name_of(cls), "state": {k: _encode(v, arrays) for k, v in vars(obj).items()}}
    raise FormatError(f"cannot save a {cls.__module__}.{cls.__qualname__} in a checkpoint")


def _name_of(cls: type) -> str:
    return f"{cls.__module__}:{cls.__qualname__}"


def _class(name: str, path: Path) -> type:
    """A class defined in semmap, by ``module:qualname``; nothing else."""
    module, _, qualname = str(name).partition(":")
    if module.split(".")[0] != "semmap" or not qualname or "<" in qualname:
        raise FormatError(f"{path}: checkpoint names a class outside semmap ({name!r})")
    try:
        found = importlib.import_module(module)
        for part in qualname.split("."):
            found = getattr(found, part)
    except (ImportError, AttributeError):
        raise FormatError(f"{path}: checkpoint names an unknown class {name!r} (written by another version?)") from None
    if not isinstance(found, type):
        raise FormatError(f"{path}: checkpoint names {name!r}, which is not a class")
    return found


def _decode(node, arrays: dict[str, np.ndarray], path: Path):
    if node is None or isinstance(node, bool | int | float | str):
        return node
    if not isinstance(node, dict) or _TAG not in node:
        raise FormatError(f"{path}: malformed checkpoint entry {str(node)[:60]!r}")
    kind = node[_TAG]
    if kind == "float":
        return float(node["value"])
    if kind == "array":
        key = f"a{int(node['index'])}"
        if key not in arrays:
            raise FormatError(f"{path}: checkpoint refers to a missing array {key}")
        a = arrays[key]
        return a[()] if node.get("scalar") else a
    if kind == "enum":
        cls = _class(node["class"], path)
        if not issubclass(cls, enum.Enum):
            raise FormatError(f"{path}: {node['class']!r} is not an Enum")
        return cls(_decode(node["value"], arrays, path))
    if kind in ("list", "tuple"):
        items = [_decode(v, arrays, path) for v in node["items"]]
        return items if kind == "list" else tuple(items)
    if kind == "dict":
        return {str(k): _decode(v, arrays, path) for k, v in dict(node["items"]).items()}
    if kind == "object":
        cls = _class(node["class"], path)
        obj = cls.__new__(cls)
        obj.__dict__.update({str(k): _decode(v, arrays, path) for k, v in dict(node["state"]).items()})
        return obj
    raise FormatError(f"{path}: unknown checkpoint entry kind {kind!r}")


def save_state(path: str | Path, obj, *, meta: dict | None = None) -> int:
    """Write ``obj`` (and a JSON-able ``meta``) to ``path`` atomically; returns the file size."""
    arrays: list[np.ndarray] = []
    body = {"format": FORMAT, "version": VERSION, "meta": meta or {}, "state": _encode(obj, arrays)}
    text = np.frombuffer(json.dumps(body).encode("utf-8"), np.uint8)

    write_atomic(path, lambda f: np.savez(f, state=text, **{f"a{i}": a for i, a in enumerate(arrays)}))
    return Path(path).stat().st_size


def load_state(path: str | Path) -> tuple[object, dict]:
    """``(obj, meta)`` from a file written by :func:`save_state`; :class:`FormatError` for anything else."""
    from semmap.files.safe import read_npz_members

    path = Path(path)
    arrays = read_npz_members(path, what="checkpoint", max_expansion=2)  # stored uncompressed
    raw = arrays.pop("state", None)
    if raw is None or raw.dtype != np.uint8 or raw.ndim != 1:
        raise FormatError(f"{path}: not a semmap checkpoint (no state description)")
    try:
        body = json.loads(raw.tobytes().decode("utf-8"))
    except (UnicodeDecodeError, ValueError) as exc:
        raise FormatError(f"{path}: checkpoint description is not JSON ({exc})") from None
    if not isinstance(body, dict) or body.get("format") != FORMAT:
        raise FormatError(f"{path}: not a semmap checkpoint")
    if body.get("version") != VERSION:
        raise FormatError(f"{path}: checkpoint version {body.get('version')!r}, this semmap reads {VERSION}")
    try:
        return _decode(body.get("state"), arrays, path), dict(body.get("meta") or {})
    except (KeyError, TypeError, ValueError, RecursionError) as exc:
        raise FormatError(f"{path}: malformed checkpoint ({type(exc).__name__}: {exc})") from None
