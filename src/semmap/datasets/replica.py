"""Replica scenes in the NICE-SLAM layout: ``results/frame%06d.jpg``, ``results/depth%06d.png`` (uint16, 6553.5
units per metre) and ``traj.txt`` (one camera-to-world 4x4 matrix per line, row-major, 16 numbers), with
``cam_params.json`` (``{"camera": {"w", "h", "fx", "fy", "cx", "cy", "scale"}}``) in the scene folder or the one
above it (else NICE-SLAM's Replica camera: 1200x680, f = 600 px).

Labels in Semantic-NeRF's naming, when present: ``semantic_class/semantic_class_<i>.png`` (Replica class ids) with
the class names of ``info_semantic.json`` (``{"classes": [{"id", "name"}, ...]}``) in the scene folder or in
``../semantic_info/<scene>/`` (Semantic-NeRF's place for it).
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from semmap.datasets.base import (
    LOG,
    FormatEntry,
    SequenceReader,
    UnreadableFileError,
    check_image_size,
    ensure_folder,
    read_color,
    read_depth,
    read_label_image,
)
from semmap.errors import ConfigError, DatasetError
from semmap.files.safe import read_text_limited
from semmap.types import CameraIntrinsics, Frame, LabelSet, check_pose, distinct_colors

DEPTH_SCALE = 6553.5
#: NICE-SLAM's Replica camera (configs/Replica/replica.yaml): width, height, fx, fy, cx, cy.
NICE_SLAM_CAMERA = (1200, 680, 600.0, 600.0, 599.5, 339.5)
FRAME_RATE = 30.0
_COLOR = re.compile(r"^frame(\d+)\.(jpg|png)$")
MAX_TRAJ_BYTES = 256 * 1024 * 1024


@dataclass(frozen=True)
class _ReplicaRef:
    index: int
    color: Path

    @property
    def name(self) -> str:
        return f"frame{self.index:06d}"


def read_trajectory(path: Path) -> np.ndarray:
    """(N, 4, 4) camera-to-world poses of ``traj.txt``; a malformed line names its number."""
    text = read_text_limited(path, MAX_TRAJ_BYTES, what="trajectory")
    poses = []
    for n, line in enumerate(text.splitlines(), 1):
        if not line.strip():
            continue
        try:
            values = np.array([float(v) for v in line.split()], np.float64)
        except ValueError:
            raise DatasetError(f"{path}: line {n} is not 16 numbers") from None
        if values.size != 16:
            raise DatasetError(f"{path}: line {n} has {values.size} numbers, expected 16 (a 4x4 matrix)")
        poses.append(values.reshape(4, 4))
    if not poses:
        raise DatasetError(f"{path}: no poses")
    return np.stack(poses)


def _camera(root: Path) -> tuple[CameraIntrinsics, float]:
    for where in (root, root.parent):
        path = where / "cam_params.json"
        if path.is_file():
            try:
                cam = json.loads(read_text_limited(path, what="camera parameters"))["camera"]
                return (CameraIntrinsics(int(cam["w"]), int(cam["h"]), float(cam["fx"]), float(cam["fy"]),
                                         float(cam["cx"]), float(cam["cy"])), float(cam.get("scale", DEPTH_SCALE)))
            except (ValueError, KeyError, TypeError) as exc:
                raise DatasetError(f"{path}: needs camera.w, h, fx, fy, cx, cy ({exc})") from None
            except ConfigError as exc:
                raise DatasetError(f"{path}: {exc}") from None
    return CameraIntrinsics(*NICE_SLAM_CAMERA), DEPTH_SCALE


def _semantic_labels(root: Path) -> LabelSet | None:
    """Names by Replica class id from ``info_semantic.json`` (ids without a name are ``class_<id>``)."""
    scene = root.name
    candidates = [root / "info_semantic.json", root.parent / "semantic_info" / scene / "info_semantic.json",
                  root.parent / "semantic_info" / re.sub(r"(\D)(\d+)$", r"\1_\2", scene) / "info_semantic.json"]
    path = next((p for p in candidates if p.is_file()), None)
    if path is None:
        return None
    try:
        classes = json.loads(read_text_limited(path, what="semantic info"))["classes"]
        by_id = {int(c["id"]): str(c["name"]) for c in classes}
    except (ValueError, KeyError, TypeError) as exc:
        raise DatasetError(f"{path}: needs classes [{{'id', 'name'}}, ...] ({exc})") from None
    if not by_id or min(by_id) < 0 or max(by_id) > 4096:
        raise DatasetError(f"{path}: class ids must lie in 0..4096")
    names = tuple(by_id.get(i, "unknown" if i == 0 else f"class_{i}") for i in range(max(by_id) + 1))
    return LabelSet(names, distinct_colors(len(names)))


class ReplicaDataset(SequenceReader[_ReplicaRef]):
    """One Replica scene folder in the NICE-SLAM layout (module docstring)."""

    def __init__(self, root: str | Path, *, stride: int = 1, max_frames: int | None = None,
                 strict: bool = False) -> None:
        root = ensure_folder(root)
        results = root / "results"
        if not results.is_dir():
            raise DatasetError(f"{root}: no results/ folder (Replica in NICE-SLAM's layout)")
        traj = root / "traj.txt"
        if not traj.is_file():
            raise DatasetError(f"{root}: no traj.txt (one camera-to-world pose per line)")
        self._poses = read_trajectory(traj)
        found = sorted((int(m.group(1)), p) for p in results.iterdir() if (m := _COLOR.match(p.name)))
        refs = [_ReplicaRef(i, p) for i, p in found if i < len(self._poses)]
        if len(refs) < len(found):
            LOG.warning("%s: %d colour frames have no pose in traj.txt (%d lines); they are left out", root,
                        len(found) - len(refs), len(self._poses))
        cam, self.depth_units = _camera(root)
        self._semantic = root / "semantic_class" if (root / "semantic_class").is_dir() else None
        labels = _semantic_labels(root) if self._semantic is not None else None
        if self._semantic is not None and labels is None:
            LOG.warning("%s: semantic_class/ without info_semantic.json; classes are named by id", root)
        super().__init__(root, refs, stride=stride, max_frames=max_frames, intrinsics=cam, label_set=labels,
                         strict=strict)

    def _labels(self, ref: _ReplicaRef) -> np.ndarray | None:
        if self._semantic is None:
            return None
        path = self._semantic / f"semantic_class_{ref.index}.png"
        if not path.is_file():
            return None
        ids = read_label_image(path)
        check_image_size(ids, self._intrinsics, path, "label")
        return ids

    def _load(self, ref: _ReplicaRef) -> Frame:
        cam = self._intrinsics
        rgb = read_color(ref.color)
        check_image_size(rgb, cam, ref.color, "colour")
        depth_path = ref.color.with_name(f"depth{ref.index:06d}.png")
        if not depth_path.is_file():
            raise UnreadableFileError(depth_path, "depth image is missing")
        depth = read_depth(depth_path, self.depth_units, invalid_values=(0,))
        check_image_size(depth, cam, depth_path, "depth")
        try:
            pose = check_pose(self._poses[ref.index], f"{self.root / 'traj.txt'} line {ref.index + 1}")
        except DatasetError as exc:
            raise UnreadableFileError(self.root / "traj.txt", str(exc)) from None
        return Frame(index=ref.index, timestamp=ref.index / FRAME_RATE, rgb=rgb, depth=depth, intrinsics=cam,
                     T_world_cam=pose, labels=self._labels(ref), name=ref.name)


def _open_replica(root: Path, *, labels, raw_color: bool, ros: dict | None, **kwargs) -> ReplicaDataset:
    if labels is not None:
        raise DatasetError(f"{root}: Replica labels are read from semantic_class/; --labels is not used")
    return ReplicaDataset(root, **kwargs)


#: Replica in NICE-SLAM's layout.
FORMAT = FormatEntry("replica", _open_replica, "Replica scene (NICE-SLAM layout): results/frame*.jpg, depth*.png, "
                     "traj.txt (+ semantic_class/ from Semantic-NeRF)",
                     detect=lambda root: (root / "traj.txt").is_file() and (root / "results").is_dir(),
                     looks_for="results/ and traj.txt (Replica, NICE-SLAM layout)")
