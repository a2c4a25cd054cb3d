"""The ROS map_server map format: an 8-bit greyscale image (PGM, or PNG with alpha) and a YAML file naming it
with the map's resolution, origin and thresholds (http://wiki.ros.org/map_server, nav2_map_server).

map_server reads pixel ``x`` as occupancy ``p = (255 - x) / 255`` (``negate: 0``); ``trinary`` mode makes
``p > occupied_thresh`` occupied, ``p < free_thresh`` free and the rest unknown; ``scale`` mode maps ``p`` between
the thresholds linearly to costs 1..99 and a transparent pixel to unknown. Row 0 of the image is the top of the map
(largest y); ``origin`` is the pose of the lower-left pixel.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from semmap.files.atomic import write_bytes_atomic, write_text_atomic
from semmap.io.product_files import read_as_map_server  # noqa: F401  (map_server's reading, beside its writing)

OCCUPIED_THRESH = 0.65
FREE_THRESH = 0.196  # ROS 1 map_saver's; above 50/255, so its unknown pixel 205 stays unknown
#: Pixels map_saver writes for trinary maps.
PIXEL_OCCUPIED, PIXEL_FREE, PIXEL_UNKNOWN = 0, 254, 205


def _image_rows(cells: np.ndarray) -> np.ndarray:
    """(nx, ny) cells (x right, y up) -> (ny, nx) image rows (row 0 at the top)."""
    return np.ascontiguousarray(np.asarray(cells).T[::-1])


def trinary_pixels(grid: np.ndarray) -> np.ndarray:
    """Image (rows, cols) uint8 of a grid of -1 unknown / 0 free / 100 occupied."""
    rows = _image_rows(grid)
    out = np.full(rows.shape, PIXEL_UNKNOWN, np.uint8)
    out[rows == 0] = PIXEL_FREE
    out[rows == 100] = PIXEL_OCCUPIED
    return out


def scale_pixels(cost: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(grey, alpha) images of a costmap (-1 unknown, 0..100) that map_server's ``scale`` mode reads back within one
    cost unit: 0 -> free, 100 -> occupied, 1..99 between the thresholds; unknown is transparent."""
    rows = _image_rows(cost).astype(np.float64)
    p = FREE_THRESH + rows / 99.0 * (OCCUPIED_THRESH - FREE_THRESH)
    p[rows <= 0] = 0.0
    p[rows >= 100] = 1.0
    grey = np.clip(np.rint(255.0 * (1.0 - p)), 0, 255).astype(np.uint8)
    alpha = np.where(rows < 0, 0, 255).astype(np.uint8)
    return grey, alpha


def pgm_bytes(image: np.ndarray) -> bytes:
    """Binary PGM (P5, maxval 255) of an 8-bit image."""
    h, w = image.shape
    return f"P5\n# semmap navigation grid\n{w} {h}\n255\n".encode() + np.ascontiguousarray(image, np.uint8).tobytes()


def png_bytes(grey: np.ndarray, alpha: np.ndarray) -> bytes:
    """PNG bytes (the grey value in each colour channel, then alpha; map_server averages the colour channels)."""
    import cv2

    ok, data = cv2.imencode(".png", np.stack([grey, grey, grey, alpha], axis=-1))
    if not ok:
        raise RuntimeError("OpenCV could not encode the costmap PNG")
    return data.tobytes()


def map_yaml(image: str, resolution: float, origin: np.ndarray, mode: str) -> str:
    """The YAML map_server reads beside ``image``."""
    x, y = (float(v) for v in origin)
    return (f"image: {image}\nmode: {mode}\nresolution: {resolution!r}\norigin: [{x!r}, {y!r}, 0.0]\nnegate: 0\n"
            f"occupied_thresh: {OCCUPIED_THRESH}\nfree_thresh: {FREE_THRESH}\n")


def write_map(out_dir: Path, stem: str, grid: np.ndarray, resolution: float, origin: np.ndarray) -> list[Path]:
    """``STEM.pgm`` + ``STEM.yaml``, trinary."""
    image = out_dir / f"{stem}.pgm"
    yaml_path = out_dir / f"{stem}.yaml"
    write_bytes_atomic(image, pgm_bytes(trinary_pixels(grid)))
    write_text_atomic(yaml_path, map_yaml(image.name, resolution, origin, "trinary"))
    return [image, yaml_path]


def write_costmap(out_dir: Path, stem: str, cost: np.ndarray, resolution: float, origin: np.ndarray) -> list[Path]:
    """``STEM.png`` (grey + alpha) + ``STEM.yaml`` in scale mode, and the exact costs as ``STEM.npy``."""
    image = out_dir / f"{stem}.png"
    yaml_path = out_dir / f"{stem}.yaml"
    exact = out_dir / f"{stem}.npy"
    write_bytes_atomic(image, png_bytes(*scale_pixels(cost)))
    write_text_atomic(yaml_path, map_yaml(image.name, resolution, origin, "scale"))
    buf = io.BytesIO()
    np.save(buf, np.asarray(cost, np.int8))
    write_bytes_atomic(exact, buf.getvalue())
    return [image, yaml_path, exact]
