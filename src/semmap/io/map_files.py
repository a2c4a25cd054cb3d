"""Saving and loading any map as one lossless ``.semmap`` file, whichever kind it is (the Python API's entry).

The semantic OctoMap writes the native format (:mod:`semmap.io.native`), the voxel grid and the point map the grid
format (:mod:`semmap.io.grid_files`); :func:`load_map` reads the header to tell them apart.  ``map.save(folder)``
writes every file of a map (``.ot``, ``.bt``, ``.ply`` too); :func:`semmap.io.octomap_files.read_octomap` reads
an ``.ot`` / ``.bt`` written by semmap or by OctoMap.
"""

from __future__ import annotations

from pathlib import Path

from semmap.errors import FormatError
from semmap.maps.base import SemanticMap
from semmap.types import MapKind


def save_map(path: str | Path, m: SemanticMap) -> int:
    """Write ``m`` (any map kind) to the ``.semmap`` file ``path`` atomically; returns its size in bytes."""
    if m.kind == MapKind.OCTOMAP:
        from semmap.io.native import save_map as save_octomap

        return save_octomap(path, m)
    from semmap.io.grid_files import save_grid

    return save_grid(path, m)


def load_map(path: str | Path) -> SemanticMap:
    """Read a ``.semmap`` file written by :func:`save_map` or by ``semmap run``: a semantic OctoMap, a voxel grid
    or a point map, as its header says (:class:`~semmap.errors.FormatError` for anything else)."""
    from semmap.io.grid_files import FORMAT as GRID_FORMAT
    from semmap.io.grid_files import load_grid
    from semmap.io.map_info import _format_of
    from semmap.io.native import FORMAT as NATIVE_FORMAT
    from semmap.io.native import load_map as load_octomap

    path = Path(path)
    kind = _format_of(path)
    if kind == GRID_FORMAT:
        return load_grid(path)
    if kind == NATIVE_FORMAT:
        return load_octomap(path)
    raise FormatError(f"{path}: not a semmap map (format {kind!r}; expected {NATIVE_FORMAT} or {GRID_FORMAT})")
