"""semmap: RGB-D sequences to 3D semantic maps (semantic OctoMap, voxel grids, object maps)."""

import os as _os

__version__ = "0.1.0"


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
