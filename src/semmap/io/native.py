"""The lossless native map format (``.semmap``): every cell's log-odds, mean colour and full top-k set.

A zip of numpy arrays (``numpy.savez_compressed``) plus a JSON header: format version, resolution, the
occupancy and fusion parameters and the label set.  ``save -> load`` gives back a map whose cells are
bit-identical.  Zip CRCs catch corruption; anything missing or malformed raises :class:`FormatError`.
"""

from __future__ import annotations

import json
import zipfile
from pathlib import Path

import numpy as np

from semmap.errors import FormatError
from semmap.io.atomic import write_atomic
from semmap.maps.semantic_octomap import CellArrays, OccupancyParams, SemanticOctoMap, SemanticParams
from semmap.types import LabelSet

FORMAT = "semmap-map"
VERSION = 1
_ARRAYS = {  # name -> (dtype, trailing shape: "k" = semantic set size)
    "packed": (np.int64, ()),
    "logodds": (np.float32, ()),
    "attr": (np.int32, ()),
    "rgb": (np.uint8, (3,)),
    "rgb_count": (np.uint16, ()),
    "sem_labels": (np.uint16, ("k",)),
    "sem_probs": (np.float32, ("k",)),
}


def save_map(path: str | Path, m: SemanticOctoMap) -> int:
    """Write ``m`` to ``path`` atomically; returns the file size in bytes."""
    c = m.cells()
    header = {
        "format": FORMAT,
        "version": VERSION,
        "resolution": m.resolution,
        "max_range": m.max_range,
        "occupancy": vars(m.occupancy),
        "semantics": vars(m.semantics),
        "label_set": None if m.label_set is None else m.label_set.to_dict(),
    }
    arrays = {name: getattr(c, name) for name in _ARRAYS}
    arrays["header"] = np.frombuffer(json.dumps(header).encode("utf-8"), np.uint8)
    write_atomic(path, lambda f: np.savez_compressed(f, **arrays))
    return Path(path).stat().st_size


def load_map(path: str | Path) -> SemanticOctoMap:
    """Read a map written by :func:`save_map`."""
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            names = set(z.files)
            missing = ({"header"} | set(_ARRAYS)) - names
            if missing:
                raise FormatError(f"{path}: not a semmap map (missing {sorted(missing)})")
            header = json.loads(bytes(z["header"]).decode("utf-8"))
            arrays = {name: z[name] for name in _ARRAYS}
    except FormatError:
        raise
    except FileNotFoundError:
        raise FormatError(f"{path}: no such file") from None
    except (zipfile.BadZipFile, EOFError, ValueError, OSError, KeyError, UnicodeDecodeError) as exc:
        raise FormatError(f"{path}: corrupt or truncated semmap file ({exc})") from None
    if header.get("format") != FORMAT:
        raise FormatError(f"{path}: not a semmap map (format {header.get('format')!r})")
    if header.get("version") != VERSION:
        raise FormatError(f"{path}: unsupported semmap map version {header.get('version')!r} (this is {VERSION})")
    try:
        semantics = SemanticParams(**header["semantics"])
        occupancy = OccupancyParams(**header["occupancy"])
        label_set = None if header["label_set"] is None else LabelSet.from_dict(header["label_set"])
        resolution = float(header["resolution"])
        max_range = float(header["max_range"])
    except (KeyError, TypeError, ValueError) as exc:
        raise FormatError(f"{path}: malformed header ({exc})") from None
    _check_arrays(path, arrays, semantics.k)
    cells = CellArrays(**arrays)
    return SemanticOctoMap.from_cells(resolution, cells, occupancy=occupancy, semantics=semantics,
                                      label_set=label_set, max_range=max_range)


def _check_arrays(path: Path, arrays: dict[str, np.ndarray], k: int) -> None:
    n_cells = arrays["packed"].shape[0]
    n_rows = arrays["rgb_count"].shape[0]
    for name, (dtype, tail) in _ARRAYS.items():
        a = arrays[name]
        rows = n_cells if name in ("packed", "logodds", "attr") else n_rows
        shape = (rows, *(k if t == "k" else t for t in tail))
        if a.dtype != dtype or a.shape != shape:
            raise FormatError(f"{path}: array {name!r} is {a.dtype}{a.shape}, expected {np.dtype(dtype)}{shape}")
    attr = arrays["attr"]
    if attr.size and (attr.min() < -1 or attr.max() >= n_rows):
        raise FormatError(f"{path}: cell attribute rows out of range")
    packed = arrays["packed"]
    if packed.size and (packed.min() < 0 or packed.max() >= 1 << 48 or np.unique(packed).size != packed.size):
        raise FormatError(f"{path}: invalid or duplicate cell keys")
