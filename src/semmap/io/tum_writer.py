"""Write frames as a TUM RGB-D sequence that :class:`~semmap.datasets.tum.TumDataset` reads back.

Shared by the tests and the simulator. Output is deterministic (same frames -> byte-identical files) and
frames are streamed, never held together.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterable
from contextlib import ExitStack
from pathlib import Path

import cv2
import numpy as np

from semmap.errors import ConfigError, DatasetError
from semmap.files.atomic import write_bytes_atomic, write_text_atomic
from semmap.types import CameraIntrinsics, Frame, LabelSet, pose_to_tum

_HEADERS = {
    "rgb.txt": "# colour images (written by semmap)\n# timestamp filename\n",
    "depth.txt": "# depth images (written by semmap)\n# timestamp filename\n",
    "groundtruth.txt": "# ground-truth trajectory T_world_cam (written by semmap)\n"
                       "# timestamp tx ty tz qx qy qz qw\n",
}


def write_tum_sequence(
    root: str | Path,
    frames: Iterable[Frame],
    *,
    depth_scale: float = 5000.0,
    write_labels: bool = True,
    label_set: LabelSet | None = None,
) -> int:
    """Write ``frames`` under ``root`` in TUM layout and return how many were written.

    Files: ``rgb/<stamp>.png``, ``depth/<stamp>.png`` (uint16, ``round(depth * depth_scale)``, 0 where invalid
    or out of the 16-bit range), ``rgb.txt``, ``depth.txt``, ``groundtruth.txt`` (frames with a pose),
    ``camera.json``; with ``write_labels`` also ``labels/<stamp>.png`` and ``instances/<stamp>.png`` (uint16)
    for frames that carry them; ``labelset.json`` if ``label_set`` is given. ``<stamp>`` is the timestamp
    with 6 decimals, which must be unique per frame.
    """
    if not depth_scale > 0:
        raise ConfigError(f"depth_scale must be positive, got {depth_scale}")
    root = Path(root)
    for folder in ("rgb", "depth"):
        (root / folder).mkdir(parents=True, exist_ok=True)
    if label_set is not None:
        write_text_atomic(root / "labelset.json", json.dumps(label_set.to_dict(), indent=1) + "\n")

    camera: CameraIntrinsics | None = None
    stamps: set[str] = set()
    with ExitStack() as stack:
        lists = {name: stack.enter_context(open(root / f".{name}.partial", "w", encoding="utf-8", newline="\n"))
                 for name in _HEADERS}
        for name, header in _HEADERS.items():
            lists[name].write(header)
        for frame in frames:
            stamp = f"{frame.timestamp:.6f}"
            if stamp in stamps:
                raise DatasetError(f"{root}: two frames share the timestamp {stamp} "
                                   f"(frame {frame.name or frame.index})")
            stamps.add(stamp)
            if camera is None:
                camera = frame.intrinsics
                write_text_atomic(root / "camera.json", json.dumps(camera.to_dict(), indent=1) + "\n")
            elif frame.intrinsics != camera:
                raise DatasetError(f"{root}: frame {stamp} has intrinsics {frame.intrinsics}, "
                                   f"the sequence started with {camera}")

            _write_png(root / "rgb" / f"{stamp}.png", cv2.cvtColor(frame.rgb, cv2.COLOR_RGB2BGR))
            _write_png(root / "depth" / f"{stamp}.png", encode_depth(frame.depth, depth_scale))
            lists["rgb.txt"].write(f"{stamp} rgb/{stamp}.png\n")
            lists["depth.txt"].write(f"{stamp} depth/{stamp}.png\n")
            if frame.T_world_cam is not None:
                row = " ".join(f"{v:.9f}" for v in pose_to_tum(frame.T_world_cam))
                lists["groundtruth.txt"].write(f"{stamp} {row}\n")
            if write_labels:
                for folder, ids in (("labels", frame.labels), ("instances", frame.instances)):
                    if ids is not None:
                        _write_png(root / folder / f"{stamp}.png", _as_uint16(ids, f"frame {stamp} {folder}"))
    for name in _HEADERS:  # complete: publish the lists
        os.replace(root / f".{name}.partial", root / name)
    return len(stamps)


def encode_depth(depth_m: np.ndarray, scale: float) -> np.ndarray:
    """uint16 depth image ``round(depth_m * scale)``; 0 for invalid, non-finite or unrepresentable depths."""
    raw = np.rint(np.asarray(depth_m, dtype=np.float64) * scale)
    valid = np.isfinite(raw) & (raw > 0) & (raw < 65535)
    return np.where(valid, raw, 0).astype(np.uint16)


def _as_uint16(ids: np.ndarray, where: str) -> np.ndarray:
    """Integer id image as uint16, refusing ids that do not fit."""
    ids = np.asarray(ids)
    if ids.size and (int(ids.min()) < 0 or int(ids.max()) > 65535):
        raise DatasetError(f"{where}: ids must be in 0..65535 to be stored as 16-bit PNG, "
                           f"got {int(ids.min())}..{int(ids.max())}")
    return ids.astype(np.uint16)


def _write_png(path: Path, image: np.ndarray) -> None:
    """Encode ``image`` as PNG and write it (folders created as needed)."""
    ok, data = cv2.imencode(".png", image)
    if not ok:
        raise DatasetError(f"{path}: cannot encode image of shape {image.shape} {image.dtype} as PNG")
    write_bytes_atomic(path, data.tobytes())
