"""Readers of the robot products ``semmap export`` and ``semmap diff`` write, for ``semmap info`` and ``view``:
the ROS map_server grids and costmaps (``map.yaml`` + ``map.pgm``, ``costmap.yaml`` + ``costmap.png``,
``costmap.npy``), the ESDF (``esdf.npz``) and the scene graph (``scene_graph.json``, spark-dsg's JSON). Each
returns plain arrays and raises a FormatError naming the file."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from semmap.errors import FormatError
from semmap.files.safe import read_text_limited

#: map_server YAML and JSON products are small; larger files are refused before they are read.
MAX_TEXT_BYTES = 64 * 1024 * 1024


@dataclass(frozen=True)
class GridImage:
    """A map_server grid as map_server reads it: ``cells[i, j]`` (x right, y up) is -1 unknown or 0..100, the cell
    with lower-left corner ``origin + (i, j) * resolution``."""

    cells: np.ndarray  # (nx, ny) int8
    resolution: float
    origin: np.ndarray  # (2,) float64
    mode: str  # trinary | scale | raw
    image: Path


def read_as_map_server(image: np.ndarray, alpha: np.ndarray | None, mode: str, occupied_thresh: float,
                       free_thresh: float, negate: int = 0) -> np.ndarray:
    """What map_server makes of an image: (nx, ny) int8 cells (-1 unknown, 0..100), x right, y up."""
    x = np.asarray(image, np.float64)
    p = x / 255.0 if negate else (255.0 - x) / 255.0
    out = np.full(x.shape, -1, np.int16)
    out[p > occupied_thresh] = 100
    out[p < free_thresh] = 0
    if mode == "scale":
        mid = (p >= free_thresh) & (p <= occupied_thresh)
        out[mid] = np.rint(99.0 * (p[mid] - free_thresh) / (occupied_thresh - free_thresh)).astype(np.int16)
        if alpha is not None:
            out[np.asarray(alpha) < 255] = -1
    return out[::-1].T.astype(np.int8)


def _map_yaml(path: Path) -> dict:
    """The keys of a map_server YAML file (``key: value`` lines, ``origin: [x, y, yaw]``)."""
    out: dict = {}
    for line in read_text_limited(path, MAX_TEXT_BYTES, what="map_server YAML").splitlines():
        key, sep, value = line.split("#")[0].partition(":")
        if sep:
            value = value.strip()
            try:
                out[key.strip()] = ([float(v) for v in value.strip("[]").split(",")] if value.startswith("[")
                                    else value if key.strip() in ("image", "mode") else float(value))
            except ValueError:
                raise FormatError(f"{path}: {key.strip()}: not a number ({value!r})") from None
    missing = [k for k in ("image", "resolution", "origin") if k not in out]
    if missing:
        raise FormatError(f"{path}: not a map_server map YAML (no {', '.join(missing)})")
    return out


def yaml_of_image(path: Path) -> Path | None:
    """The map_server YAML beside an image that names it (``map.pgm`` -> ``map.yaml``), or None."""
    yaml_path = path.with_suffix(".yaml")
    if not yaml_path.is_file():
        return None
    try:
        return yaml_path if Path(_map_yaml(yaml_path)["image"]).name == path.name else None
    except FormatError:
        return None


def read_image(path: str | Path) -> np.ndarray:
    """The pixels of a PNG or PGM as stored (grey, or colour in BGR with alpha when present)."""
    import cv2

    from semmap.files.safe import regular_file_size

    regular_file_size(path, what="image")
    pixels = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if pixels is None or pixels.ndim not in (2, 3):
        raise FormatError(f"{path}: not an image OpenCV reads")
    return pixels


def read_map_server(path: str | Path) -> GridImage:
    """A map_server grid from its YAML file, or from its image when a YAML beside names it."""
    path = Path(path)
    if path.suffix in (".pgm", ".png"):
        found = yaml_of_image(path)
        if found is None:
            raise FormatError(f"{path}: no map_server YAML beside it names this image ({path.with_suffix('.yaml')})")
        path = found
    spec = _map_yaml(path)
    image_path = path.parent / str(spec["image"])
    origin = np.asarray(spec["origin"], np.float64).reshape(-1)
    if len(origin) < 2 or not np.isfinite(origin).all() or not spec["resolution"] > 0:
        raise FormatError(f"{path}: origin must be [x, y, yaw] and resolution positive")
    if not image_path.is_file():
        raise FormatError(f"{path}: its image {image_path} is missing")
    pixels = read_image(image_path)
    alpha = pixels[..., 3] if pixels.ndim == 3 and pixels.shape[2] == 4 else None
    grey = pixels if pixels.ndim == 2 else pixels[..., :3].mean(axis=2)
    mode = str(spec.get("mode", "trinary"))
    cells = read_as_map_server(grey, alpha, mode, float(spec.get("occupied_thresh", 0.65)),
                               float(spec.get("free_thresh", 0.196)), int(spec.get("negate", 0)))
    return GridImage(cells, float(spec["resolution"]), origin[:2], mode, image_path)


def read_costmap_npy(path: str | Path) -> GridImage:
    """``costmap.npy`` (exact int8 costs, -1 unknown), placed by the ``costmap.yaml`` beside it."""
    path = Path(path)
    try:
        cells = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as exc:
        raise FormatError(f"{path}: not a NumPy array file ({exc})") from None
    if cells.ndim != 2 or cells.dtype.kind not in "iu" or (cells.size and (cells.min() < -1 or cells.max() > 100)):
        raise FormatError(f"{path}: not a costmap (2D integer costs -1..100), got {cells.dtype} {cells.shape}")
    yaml_path = path.with_suffix(".yaml")
    spec = _map_yaml(yaml_path) if yaml_path.is_file() else {"resolution": 1.0, "origin": [0.0, 0.0]}
    return GridImage(cells.astype(np.int8), float(spec["resolution"]), np.asarray(spec["origin"][:2], np.float64),
                     "raw", path)


def read_esdf_npz(path: str | Path) -> dict[str, np.ndarray]:
    """``esdf.npz`` of ``semmap export esdf``: distance (nx, ny, nz) float32, observed bool, origin (3,),
    resolution."""
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            out = {k: np.asarray(z[k]) for k in ("distance", "observed", "origin", "resolution")}
    except (OSError, ValueError, KeyError) as exc:
        raise FormatError(f"{path}: not an esdf.npz written by semmap export esdf ({exc})") from None
    if out["distance"].ndim != 3 or out["observed"].shape != out["distance"].shape or out["origin"].shape != (3,):
        raise FormatError(f"{path}: distance, observed and origin do not fit together")
    return out


@dataclass(frozen=True)
class GraphNode:
    """A node of a scene graph: an object (``O``) or a room (``R``), its box centre and size (m)."""

    layer: str  # "object" | "room"
    name: str
    label: int | None
    center: np.ndarray  # (3,)
    size: np.ndarray  # (3,)


def read_json_limited(path: str | Path, what: str) -> object:
    """A JSON file of at most :data:`MAX_TEXT_BYTES` (FormatError naming it otherwise)."""
    try:
        return json.loads(read_text_limited(path, MAX_TEXT_BYTES, what=what))
    except ValueError as exc:
        raise FormatError(f"{path}: not JSON ({exc})") from None


def read_scene_graph(path: str | Path) -> tuple[list[GraphNode], list[tuple[str, int, int]]]:
    """The nodes and edges ``(relation, node, node)`` (indices into the nodes) of a ``scene_graph.json``."""
    data = read_json_limited(path, "scene graph")
    if not isinstance(data, dict) or "SPARK_DSG_header" not in data:
        raise FormatError(f"{path}: not a spark-dsg scene graph (no SPARK_DSG_header)")
    nodes, index = [], {}
    try:
        for n in data["nodes"]:
            a = n["attributes"]
            kind = {"ObjectNodeAttributes": "object", "RoomNodeAttributes": "room"}.get(a.get("type"))
            if kind is None:
                continue
            box = a.get("bounding_box") or {}
            center = np.asarray(box.get("world_P_center", a["position"]), np.float64)
            index[n["id"]] = len(nodes)
            nodes.append(GraphNode(kind, str(a.get("name", "")), a.get("semantic_label"), center,
                                   np.asarray(box.get("dimensions", (0.0, 0.0, 0.0)), np.float64)))
        edges = [(str(e.get("info", {}).get("metadata", {}).get("relation", "")), index[e["source"]],
                  index[e["target"]]) for e in data["edges"] if e["source"] in index and e["target"] in index]
    except (KeyError, TypeError, ValueError) as exc:
        raise FormatError(f"{path}: malformed scene graph ({type(exc).__name__}: {exc})") from None
    return nodes, edges
