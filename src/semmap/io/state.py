"""A checkpoint file: a versioned JSON header and named numpy arrays in one uncompressed ``.npz``, written atomically.

The names are the checkpoint schema (``maps/0/table_keys``, ``record/poses``, ...), chosen by the objects that
save their state (``state()`` / ``restore(state)`` on maps, schedulers, pose sources and the run record), never
the private attribute names that hold the arrays: renaming an attribute cannot change a checkpoint. Nothing but
numbers, strings and arrays is read back (no pickle, no class looked up by name), so a damaged or hostile
checkpoint is a :class:`FormatError`, never code execution.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from semmap.errors import FormatError
from semmap.files.atomic import write_atomic

FORMAT = "semmap-checkpoint"
#: Checkpoint schema version; a checkpoint of another one is refused in one line (``--resume`` starts over).
VERSION = 2
_HEADER = "header"


def write_checkpoint(path: str | Path, header: dict, arrays: dict[str, np.ndarray]) -> int:
    """Write ``header`` (JSON-able) and ``arrays`` to ``path`` atomically; returns the file size in bytes."""
    if _HEADER in arrays:
        raise ValueError(f"{_HEADER!r} is the checkpoint's own member")
    body = {"format": FORMAT, "version": VERSION, **header}
    text = np.frombuffer(json.dumps(body).encode("utf-8"), np.uint8)
    write_atomic(path, lambda f: np.savez(f, **{_HEADER: text}, **arrays))
    return Path(path).stat().st_size


def read_checkpoint(path: str | Path) -> tuple[dict, dict[str, np.ndarray]]:
    """``(header, arrays)`` of a file written by :func:`write_checkpoint`; :class:`FormatError` for anything
    else, naming what is wrong (another format or schema version included)."""
    from semmap.files.safe import json_from_bytes, read_npz_members

    path = Path(path)
    arrays = read_npz_members(path, what="checkpoint", max_expansion=2)  # stored uncompressed
    raw = arrays.pop(_HEADER, None)
    if raw is None or raw.dtype != np.uint8 or raw.ndim != 1:
        raise FormatError(f"{path}: not a semmap checkpoint (no header)")
    header = json_from_bytes(path, raw.tobytes(), what="checkpoint header")
    if not isinstance(header, dict) or header.get("format") != FORMAT:
        raise FormatError(f"{path}: not a semmap checkpoint (format {header.get('format')!r})"
                          if isinstance(header, dict) else f"{path}: not a semmap checkpoint")
    if header.get("version") != VERSION:
        raise FormatError(f"{path}: checkpoint schema version {header.get('version')!r}, this semmap reads "
                          f"{VERSION} (written by another semmap version)")
    return header, arrays


def section(arrays: dict[str, np.ndarray], prefix: str) -> dict[str, np.ndarray]:
    """The arrays stored under ``prefix/`` with the prefix taken off (one object's state)."""
    head = f"{prefix}/"
    return {name[len(head):]: a for name, a in arrays.items() if name.startswith(head)}


def prefixed(prefix: str, state: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """``state``'s arrays named ``prefix/name`` (the inverse of :func:`section`)."""
    return {f"{prefix}/{name}": np.asarray(a) for name, a in state.items()}

