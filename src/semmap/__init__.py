"""semmap: RGB-D sequences to 3D semantic maps (semantic OctoMap, voxel grids, object maps).

The main nouns are importable from here (``from semmap import Mapper, SemanticOctoMap``); each is imported on
first use, so ``import semmap`` stays fast.  Building a map from your own frames:

    mapper = semmap.Mapper([semmap.SemanticOctoMap(0.05, label_set=labels)], min_depth=0.1, max_depth=5.0)
    mapper.integrate_arrays(rgb, depth_m, K, T_world_cam, class_ids)   # once per frame
    labels, confidence = mapper.maps[0].class_at(points)

See ``docs/python_api.md`` and ``examples/python_api.py``.
"""

import os as _os

__version__ = "0.1.0"

#: Public name -> module that defines it (imported lazily by :func:`__getattr__`).
_EXPORTS = {
    # inputs: datasets, frames, cameras, classes
    "open_dataset": "semmap.datasets",
    "SimulatedDataset": "semmap.datasets.simulated",
    "Frame": "semmap.types",
    "CameraIntrinsics": "semmap.types",
    "LabelSet": "semmap.types",
    "TopKProbs": "semmap.types",
    "EMPTY_LABEL": "semmap.types",
    "MapKind": "semmap.maps.registry",
    "MapCloud": "semmap.types",
    "frame_from_arrays": "semmap.frame_arrays",
    "class_sets": "semmap.frame_arrays",
    "make_segmenter": "semmap.perception.registry",
    # maps, fusion and their queries
    "SemanticMap": "semmap.maps.base",
    "voxels_of_class": "semmap.maps.base",
    "SemanticOctoMap": "semmap.maps.semantic_octomap",
    "OccupancyParams": "semmap.maps.semantic_octomap",
    "SemanticVoxelGrid": "semmap.maps.voxel_grid",
    "SemanticPointMap": "semmap.maps.point_map",
    "TsdfMap": "semmap.maps.tsdf",
    "semantic_mesh": "semmap.maps.mesh",
    "FusionParams": "semmap.fusion.rules",
    "FusionRule": "semmap.fusion.rules",
    "get_map": "semmap.factories",
    # the frame loop and whole runs
    "Mapper": "semmap.pipeline",
    "RunConfig": "semmap.config",
    "run_config": "semmap.runner",
    # files
    "save_map": "semmap.io.map_files",
    "load_map": "semmap.io.map_files",
    "save_map_files": "semmap.io.map_files",
    "read_octomap": "semmap.io.octomap_files",
    "read_ply": "semmap.io.ply",
    "write_ply": "semmap.io.ply",
    "write_mesh_ply": "semmap.io.mesh_ply",
    # errors
    "SemmapError": "semmap.errors",
    "ConfigError": "semmap.errors",
    "DatasetError": "semmap.errors",
    "FormatError": "semmap.errors",
}
__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    """Import a public name's module on first use (PEP 562) and keep the name here."""
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'semmap' has no attribute {name!r}")
    import importlib

    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted({*globals(), *_EXPORTS})


def _configure_numba() -> None:
    """Threading layer and a compiled-kernel cache keyed by the package's source.

    open3d ships an older TBB that numba rejects with a warning, so OpenMP comes first.  numba's own cache only
    notices edits to the file of the cached function, not to kernels it calls from other files; keying the
    cache folder by a hash of all of semmap's sources makes any edit or upgrade recompile everything.
    """
    import hashlib
    import sys
    from pathlib import Path

    _os.environ.setdefault("NUMBA_THREADING_LAYER_PRIORITY", "omp workqueue tbb")
    if "NUMBA_CACHE_DIR" in _os.environ:
        return
    here = Path(__file__).parent
    digest = hashlib.sha1()
    for path in sorted(here.rglob("*.py")):
        source = path.read_bytes()
        if b"import numba" in source or b"from numba" in source:
            digest.update(path.relative_to(here).as_posix().encode())
            digest.update(source)
    root = Path(_os.environ.get("SEMMAP_CACHE_DIR", Path.home() / ".cache" / "semmap"))
    cache = root / f"numba-{__version__}-{digest.hexdigest()[:12]}"
    try:
        cache.mkdir(parents=True, exist_ok=True)
        import shutil
        import time

        for old in root.glob("numba-*"):  # caches of earlier sources are dead weight after a while
            if old != cache and old.is_dir() and time.time() - old.stat().st_mtime > 24 * 3600:
                shutil.rmtree(old, ignore_errors=True)
    except OSError:
        return  # read-only home: numba falls back to its default locations
    _os.environ["NUMBA_CACHE_DIR"] = str(cache)
    if "numba" in sys.modules:  # imported before us: set its config too
        sys.modules["numba"].config.CACHE_DIR = str(cache)


_configure_numba()


def _configure_opencv() -> None:
    """Cap OpenCV's image decoder and silence its own log lines before anything imports ``cv2``."""
    from semmap.files.safe import limit_opencv

    limit_opencv()


_configure_opencv()
