"""Every map's files in a run folder, written and read from the maps' public arrays (maps never import io/).

``save_map_files`` writes the files of any map kind (the OctoMap's ``map.ot`` / ``map.bt`` / ``map.semmap``, a
voxel grid's or point map's ``<kind>.semmap`` and ``<kind>.ply``, the TSDF's ``tsdf.semmap`` and its semantic mesh
``mesh.ply``); ``save_map`` writes one lossless ``.semmap`` of
any kind and ``load_map`` reads any ``.semmap`` back (the Python API's pair).
"""

from __future__ import annotations

from pathlib import Path

from semmap.errors import FormatError
from semmap.files.safe import json_from_bytes, read_npz_members
from semmap.io import grid_files, native
from semmap.io.octomap_files import write_bt, write_ot
from semmap.io.ply import write_ply
from semmap.maps.base import SemanticMap
from semmap.maps.registry import MapKind
from semmap.maps.semantic_octomap import SemanticOctoMap

#: The files each map kind writes, in the order they are written (lossless ``.semmap`` of a grid first).
MAP_FILES: dict[MapKind, tuple[str, ...]] = {
    MapKind.OCTOMAP: ("map.ot", "map.bt", "map.semmap"),
    MapKind.VOXELGRID: ("voxelgrid.semmap", "voxelgrid.ply"),
    MapKind.POINTS: ("points.semmap", "points.ply"),
    MapKind.TSDF: ("tsdf.semmap", "mesh.ply"),
}


def native_file(kind: MapKind) -> str:
    """Name of the lossless ``.semmap`` file a map of ``kind`` writes."""
    return next(name for name in MAP_FILES[kind] if name.endswith(".semmap"))


def save_map_files(m: SemanticMap, out_dir: str | Path, *, labels_from: SemanticMap | None = None
                   ) -> dict[str, int]:
    """Write ``m``'s files (:data:`MAP_FILES`) into ``out_dir``, each atomically; returns ``{file name: bytes}``.
    A TSDF's mesh takes its classes from ``labels_from`` (the run's semantic map), else from the TSDF's own."""
    out_dir = Path(out_dir)
    if m.kind == MapKind.OCTOMAP:
        return _save_octomap(m, out_dir)
    if m.kind not in MAP_FILES:
        raise FormatError(f"no file format for map kind {m.kind!r}")
    name, ply = MAP_FILES[m.kind]
    if m.kind == MapKind.TSDF:
        from semmap.io.mesh_ply import write_mesh_ply
        from semmap.maps.mesh import semantic_mesh

        return {name: grid_files.save_grid(out_dir / name, m),
                ply: write_mesh_ply(out_dir / ply, semantic_mesh(m, labels_from))}
    return {name: grid_files.save_grid(out_dir / name, m), ply: write_ply(out_dir / ply, m.cloud())}


def _save_octomap(m: SemanticOctoMap, out_dir: Path) -> dict[str, int]:
    """``map.ot`` (ColorOcTree, voxel colour by the map's ``color_mode``), ``map.bt`` and lossless ``map.semmap``."""
    ot, bt, semmap = MAP_FILES[MapKind.OCTOMAP]
    tree = m.file_tree()
    return {
        ot: write_ot(out_dir / ot, tree, m.resolution, color=True),
        bt: write_bt(out_dir / bt, tree, m.resolution, float(m.occupancy.threshold_log)),
        semmap: native.save_map(out_dir / semmap, m),
    }


def save_map(path: str | Path, m: SemanticMap) -> int:
    """Write ``m`` (any map kind) to the lossless ``.semmap`` file ``path`` atomically; returns its size in bytes."""
    if m.kind == MapKind.OCTOMAP:
        return native.save_map(path, m)
    return grid_files.save_grid(path, m)


def semmap_format(path: str | Path) -> str | None:
    """The ``format`` field of a ``.semmap`` file's JSON header (``semmap-map`` or ``semmap-grid``), None if absent."""
    path = Path(path)
    header = json_from_bytes(path, read_npz_members(path, ["header"], what="semmap map")["header"].tobytes())
    return header.get("format") if isinstance(header, dict) else None


def load_map(path: str | Path) -> SemanticMap:
    """Any map from its ``.semmap`` file: a voxel grid or point map if its header says so, else the OctoMap."""
    if semmap_format(path) == grid_files.FORMAT:
        return grid_files.load_grid(path)
    return native.load_map(path)
