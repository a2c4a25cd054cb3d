"""Sequences written in the layouts of the field's benchmarks, so their readers are tested on files semmap made:
a ScanNet scan (``<scan>.sens``, ``label-filt/``, ``instance-filt/``, ``scannetv2-labels.combined.tsv``) and a
Replica scene in NICE-SLAM's layout with Semantic-NeRF's label files. The formats are described where they are
read (``semmap.datasets.scannet`` and ``semmap.datasets.replica``)."""

from __future__ import annotations

import json
import struct
import zlib
from collections.abc import Iterable
from pathlib import Path

import cv2
import numpy as np

from semmap.errors import ConfigError
from semmap.files.atomic import write_bytes_atomic, write_text_atomic
from semmap.types import Frame, LabelSet

SCANNET_DEPTH_SHIFT = 1000.0
REPLICA_DEPTH_SCALE = 6553.5


def _png(image: np.ndarray) -> bytes:
    ok, data = cv2.imencode(".png", image)
    if not ok:
        raise ConfigError("OpenCV could not encode a PNG")
    return data.tobytes()


def _jpeg(rgb: np.ndarray) -> bytes:
    ok, data = cv2.imencode(".jpg", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, 95])
    if not ok:
        raise ConfigError("OpenCV could not encode a JPEG")
    return data.tobytes()


def _depth_units(depth: np.ndarray, scale: float) -> np.ndarray:
    units = np.rint(np.nan_to_num(depth, nan=0.0) * scale)
    units[(units < 0) | (units > 65535)] = 0
    return units.astype(np.uint16)


def _matrix(K: np.ndarray) -> list[float]:
    return [float(v) for v in np.asarray(K, np.float32).ravel()]


def write_scannet_scan(root: Path, frames: Iterable[Frame], label_set: LabelSet, nyu40_of: np.ndarray,
                       nyu40_names: tuple[str, ...], scan: str = "scene0000_00") -> int:
    """Write ``frames`` as a ScanNet scan under ``root``; label ids are the frames' class ids, mapped to NYU-40 by
    ``nyu40_of`` in the tsv. Returns the number of frames."""
    root.mkdir(parents=True, exist_ok=True)
    (root / "label-filt").mkdir(exist_ok=True)
    (root / "instance-filt").mkdir(exist_ok=True)
    path = root / f"{scan}.sens"
    n = 0
    with open(path, "w+b") as f:
        count_at = None
        for frame in frames:
            if count_at is None:
                count_at = _sens_header(f, frame)
            pose = frame.T_world_cam if frame.T_world_cam is not None else np.full((4, 4), -np.inf)
            color, depth = _jpeg(frame.rgb), zlib.compress(_depth_units(frame.depth, SCANNET_DEPTH_SHIFT).tobytes())
            stamp = round(frame.timestamp * 1e6)
            f.write(struct.pack("<16f4Q", *_matrix(pose), stamp, stamp, len(color), len(depth)) + color + depth)
            if frame.labels is not None:
                write_bytes_atomic(root / "label-filt" / f"{n}.png", _png(frame.labels.astype(np.uint16)))
            if frame.instances is not None:
                write_bytes_atomic(root / "instance-filt" / f"{n}.png",
                                   _png(np.clip(frame.instances, 0, 255).astype(np.uint8)))
            n += 1
        if count_at is None:
            raise ConfigError("no frames to write")
        f.write(struct.pack("<Q", 0))  # no IMU records
        f.seek(count_at)
        f.write(struct.pack("<Q", n))
    rows = ["id\traw_category\tcategory\tcount\tnyu40id\tnyu40class"]
    rows += [f"{i}\t{name}\t{name}\t0\t{int(nyu40_of[i])}\t{nyu40_names[int(nyu40_of[i])]}"
             for i, name in enumerate(label_set.names) if i > 0]
    write_text_atomic(root / "scannetv2-labels.combined.tsv", "\n".join(rows) + "\n")
    return n


def _sens_header(f, frame: Frame) -> int:
    """Write the .sens header for frames like ``frame``; returns the offset of the frame count."""
    cam = frame.intrinsics
    K = np.array([[cam.fx, 0, cam.cx, 0], [0, cam.fy, cam.cy, 0], [0, 0, 1, 0], [0, 0, 0, 1]])
    name = b"semmap simulator"
    f.write(struct.pack("<IQ", 4, len(name)) + name)
    f.write(struct.pack("<64f", *_matrix(K), *_matrix(np.eye(4)), *_matrix(K), *_matrix(np.eye(4))))
    f.write(struct.pack("<2i4If", 2, 1, cam.width, cam.height, cam.width, cam.height, SCANNET_DEPTH_SHIFT))
    at = f.tell()
    f.write(struct.pack("<Q", 0))
    return at


def write_replica_scene(root: Path, frames: Iterable[Frame], label_set: LabelSet) -> int:
    """Write ``frames`` as a Replica scene in NICE-SLAM's layout with Semantic-NeRF's label files under ``root``."""
    (root / "results").mkdir(parents=True, exist_ok=True)
    (root / "semantic_class").mkdir(exist_ok=True)
    poses, camera, n = [], None, 0
    for frame in frames:
        camera = frame.intrinsics
        write_bytes_atomic(root / "results" / f"frame{n:06d}.jpg", _jpeg(frame.rgb))
        write_bytes_atomic(root / "results" / f"depth{n:06d}.png", _png(_depth_units(frame.depth,
                                                                                    REPLICA_DEPTH_SCALE)))
        if frame.labels is not None:
            write_bytes_atomic(root / "semantic_class" / f"semantic_class_{n}.png",
                               _png(frame.labels.astype(np.uint16)))
        pose = frame.T_world_cam if frame.T_world_cam is not None else np.full((4, 4), np.nan)
        poses.append(" ".join(f"{v:.9g}" for v in np.asarray(pose).ravel()))
        n += 1
    if camera is None:
        raise ConfigError("no frames to write")
    write_text_atomic(root / "traj.txt", "\n".join(poses) + "\n")
    cam = {"camera": {"w": camera.width, "h": camera.height, "fx": camera.fx, "fy": camera.fy, "cx": camera.cx,
                      "cy": camera.cy, "scale": REPLICA_DEPTH_SCALE}}
    write_text_atomic(root / "cam_params.json", json.dumps(cam, indent=1) + "\n")
    classes = [{"id": i, "name": name} for i, name in enumerate(label_set.names)]
    write_text_atomic(root / "info_semantic.json", json.dumps({"classes": classes}, indent=1) + "\n")
    return n
