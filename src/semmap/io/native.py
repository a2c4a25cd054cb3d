"""The lossless native map format (``.semmap``): every cell's log-odds, mean colour and full fusion state.

A zip of numpy arrays (``numpy.savez_compressed``) plus a JSON header: format version, resolution, the
occupancy and fusion parameters and the label set.  ``save -> load`` gives back a map whose cells are
bit-identical.  Zip CRCs catch corruption; anything missing or malformed raises :class:`FormatError`.

The header's ``semantics`` names the fusion rule (``rule``, with all of ``FusionParams``' settings); a ``topk``
map writes only ``k``, ``lam`` and ``max_confidence`` there, as every file did before the OctoMap took other
rules, and a header without ``rule`` reads as ``topk``.  ``sem_labels`` / ``sem_probs`` hold the rule's state:
(rows, k) pairs for ``topk``, (rows, 1) for ``max``, (rows, 0) labels and (rows, K) values for the full-K rules.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from semmap.errors import FormatError, SemmapError
from semmap.files.atomic import write_atomic
from semmap.files.safe import json_from_bytes
from semmap.fusion.rules import FusionParams, FusionRule
from semmap.limits import check_file_resolution
from semmap.maps.semantic_octomap import CellArrays, OccupancyParams, SemanticOctoMap
from semmap.types import LabelSet

FORMAT = "semmap-map"
VERSION = 1
_ARRAYS = {  # name -> (dtype, trailing shape: "S" / "W" = the fusion state's labels / values per row)
    "packed": (np.int64, ()),
    "logodds": (np.float32, ()),
    "attr": (np.int32, ()),
    "rgb": (np.uint8, (3,)),
    "rgb_count": (np.uint16, ()),
    "sem_labels": (np.uint16, ("S",)),
    "sem_probs": (np.float32, ("W",)),
}
_TOPK_KEYS = ("k", "lam", "max_confidence")


def _semantics_header(f: FusionParams) -> dict:
    """The header's fusion settings: the version-1 ``topk`` form, or every setting with the rule's name."""
    if f.rule == FusionRule.TOPK:
        return {key: getattr(f, key) for key in _TOPK_KEYS}
    return f.to_dict()


def save_map(path: str | Path, m: SemanticOctoMap) -> int:
    """Write ``m`` to ``path`` atomically; returns the file size in bytes."""
    c = m.cells()
    header = {
        "format": FORMAT,
        "version": VERSION,
        "resolution": m.resolution,
        "max_range": m.max_range,
        "occupancy": vars(m.occupancy),
        "semantics": _semantics_header(m.fusion),
        "label_set": None if m.label_set is None else m.label_set.to_dict(),
    }
    arrays = {name: getattr(c, name) for name in _ARRAYS}
    arrays["header"] = np.frombuffer(json.dumps(header).encode("utf-8"), np.uint8)
    write_atomic(path, lambda f: np.savez_compressed(f, **arrays))
    return Path(path).stat().st_size


#: A ``.semmap``'s arrays may expand to at most this many times the file's size (numpy's deflate of map arrays
#: reaches 3-10x; a zip bomb thousands) ...
MAX_EXPANSION = 100
#: ... or to this many bytes, whichever is larger (small files of very regular arrays).
MIN_EXPANSION_BUDGET = 64 * 2**20
#: Largest JSON header accepted.
MAX_HEADER_BYTES = 16 * 2**20


def load_map(path: str | Path) -> SemanticOctoMap:
    """Read a map written by :func:`save_map`.

    Hostile files are refused before anything large is allocated: the zip's members must be the expected arrays,
    their declared sizes must fit a budget tied to the file's size (no zip bombs), and each array's own header
    (dtype, shape) must match the bytes its member holds and what the map needs."""
    from semmap.files.safe import read_npz_members

    path = Path(path)
    arrays = read_npz_members(path, ["header", *_ARRAYS], what="semmap map", max_expansion=MAX_EXPANSION,
                              min_budget=MIN_EXPANSION_BUDGET)
    raw = arrays.pop("header")
    if raw.dtype != np.uint8 or raw.ndim != 1 or raw.size > MAX_HEADER_BYTES:
        raise FormatError(f"{path}: header must be a 1-D uint8 array of JSON of at most {MAX_HEADER_BYTES:,} bytes")
    resolution, max_range, occupancy, fusion, label_set = _parse_header(path, raw.tobytes())
    try:
        widths = fusion.entry.widths(fusion, 0 if label_set is None else len(label_set))
    except SemmapError as exc:
        raise FormatError(f"{path}: malformed header ({exc})") from None
    _check_arrays(path, arrays, widths, dense=fusion.entry.dense)
    cells = CellArrays(**arrays)
    try:
        return SemanticOctoMap.from_cells(resolution, cells, occupancy=occupancy, fusion=fusion, label_set=label_set,
                                          max_range=max_range)
    except SemmapError as exc:
        raise FormatError(f"{path}: malformed header ({exc})") from None


def _number(header: dict, key: str, path: Path) -> float:
    value = header.get(key)
    if isinstance(value, bool) or not isinstance(value, int | float) or not np.isfinite(value):
        raise FormatError(f"{path}: header field {key!r} must be a finite number, got {value!r}")
    return float(value)


def _parse_header(path: Path, raw: bytes):
    """(resolution, max_range, occupancy, semantics, label set) from the JSON header, every field type-checked."""
    header = json_from_bytes(path, raw)
    if not isinstance(header, dict):
        raise FormatError(f"{path}: header must be a JSON object, got {type(header).__name__}")
    if header.get("format") != FORMAT:
        raise FormatError(f"{path}: not a semmap map (format {header.get('format')!r})")
    if header.get("version") != VERSION:
        raise FormatError(f"{path}: unsupported semmap map version {header.get('version')!r} (this is {VERSION})")
    resolution = check_file_resolution(_number(header, "resolution", path), path)
    max_range = _number(header, "max_range", path)
    parts = {}
    for key in ("occupancy", "semantics"):
        section = header.get(key)
        if not isinstance(section, dict) or not all(isinstance(k, str) for k in section):
            raise FormatError(f"{path}: header field {key!r} must be a JSON object, got {section!r:.60}")
        parts[key] = {k: _number(section, k, path) for k in section if k not in ("rule", "prior")}
    semantics = dict(parts["semantics"])
    if "k" in semantics:
        if semantics["k"] != int(semantics["k"]):
            raise FormatError(f"{path}: semantic set size k must be a whole number, got {semantics['k']}")
        semantics["k"] = int(semantics["k"])
    section = header["semantics"]
    semantics["rule"] = section.get("rule", FusionRule.TOPK.value)
    if not isinstance(semantics["rule"], str):
        raise FormatError(f"{path}: header field 'rule' must be a fusion rule's name, got {semantics['rule']!r:.60}")
    prior = section.get("prior")
    if prior is not None:
        if not isinstance(prior, list) or not all(isinstance(v, int | float) and not isinstance(v, bool)
                                                  for v in prior):
            raise FormatError(f"{path}: header field 'prior' must be a list of numbers or null")
        semantics["prior"] = np.array(prior, np.float64)
    label_set = header.get("label_set")
    if label_set is not None and not isinstance(label_set, dict):
        raise FormatError(f"{path}: header field 'label_set' must be a JSON object or null")
    try:
        return (resolution, max_range, OccupancyParams(**parts["occupancy"]), FusionParams(**semantics),
                None if label_set is None else LabelSet.from_dict(label_set))
    except (TypeError, SemmapError) as exc:
        raise FormatError(f"{path}: malformed header ({exc})") from None


def _check_arrays(path: Path, arrays: dict[str, np.ndarray], widths: tuple[int, int], *, dense: bool) -> None:
    n_cells = arrays["packed"].shape[0]
    n_rows = arrays["rgb_count"].shape[0]
    size = {"S": widths[0], "W": widths[1]}
    for name, (dtype, tail) in _ARRAYS.items():
        a = arrays[name]
        rows = n_cells if name in ("packed", "logodds", "attr") else n_rows
        shape = (rows, *(size.get(t, t) for t in tail))
        if a.dtype != dtype or a.shape != shape:
            raise FormatError(f"{path}: array {name!r} is {a.dtype}{a.shape}, expected {np.dtype(dtype)}{shape}")
    if not np.isfinite(arrays["logodds"]).all():
        raise FormatError(f"{path}: cells with non-finite (NaN or infinite) log-odds")
    probs = arrays["sem_probs"]
    if probs.size and not np.isfinite(probs).all():
        raise FormatError(f"{path}: non-finite class evidence")
    if probs.size and not dense and not (probs.min() >= 0 and probs.max() <= 1):
        raise FormatError(f"{path}: class probabilities outside [0, 1]")
    attr = arrays["attr"]
    if attr.size and (attr.min() < -1 or attr.max() >= n_rows):
        raise FormatError(f"{path}: cell attribute rows out of range")
    packed = arrays["packed"]
    if packed.size and (packed.min() < 0 or packed.max() >= 1 << 48 or np.unique(packed).size != packed.size):
        raise FormatError(f"{path}: invalid or duplicate cell keys")
