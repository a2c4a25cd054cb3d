"""semmap from your own loop: build a semantic map frame by frame from plain numpy arrays, then query it.

A robot's driver or ROS 2 node hands over colour, depth in metres, the camera matrix, the camera pose and a
per-pixel class image (or class probabilities) for every frame.  Here the built-in simulator stands in for the
robot: each frame is turned into those plain arrays before semmap sees it.

    PYTHONPATH=src python examples/python_api.py [OUT_DIR]
"""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

import numpy as np

import semmap


def robot_frames(robot: semmap.SimulatedDataset):
    """(rgb uint8 (H, W, 3), depth float32 metres (H, W), K (3, 3), T_world_cam (4, 4), class ids (H, W)) per frame,
    as a user's own driver would give them (here rendered by the simulator)."""
    for frame in robot:
        yield frame.rgb, frame.depth, frame.intrinsics.K, frame.T_world_cam, frame.labels


def build_and_query(out_dir: Path, frames: int = 20) -> dict:
    """Map ``frames`` frames into a semantic OctoMap and a voxel grid, query both, save and reload the OctoMap."""
    robot = semmap.SimulatedDataset.default(frames=frames)
    labels = robot.label_set  # your segmenter's classes; semmap.LabelSet.generic(n) numbers n classes
    octomap = semmap.SemanticOctoMap(0.05, label_set=labels)
    grid = semmap.SemanticVoxelGrid(0.05, label_set=labels)
    mapper = semmap.Mapper([octomap, grid], min_depth=0.1, max_depth=6.0)

    for i, (rgb, depth, K, T_world_cam, class_ids) in enumerate(robot_frames(robot)):
        mapper.integrate_arrays(rgb, depth, K, T_world_cam, class_ids, index=i)

    # voxels of a class, and the class at any points (EMPTY_LABEL where nothing occupied is there)
    floor = semmap.voxels_of_class(octomap, "floor")
    chairs = semmap.voxels_of_class(grid, "chair")
    probe = np.array([floor[0], [0.0, 0.0, 50.0]])
    probe_labels, probe_conf = octomap.class_at(probe)
    grid_labels, _ = grid.class_at(floor)

    # save, load back, ask again
    path = out_dir / "map.semmap"
    semmap.save_map(path, octomap)
    loaded = semmap.load_map(path)
    same = bool(np.array_equal(loaded.class_at(floor)[0], octomap.class_at(floor)[0]))
    return {
        "frames": frames,
        "points_integrated": mapper.points_integrated,
        "occupied_voxels": octomap.num_occupied,
        "floor_voxels": len(floor),
        "floor_height_m": float(np.median(floor[:, 2])) if len(floor) else float("nan"),
        "chair_voxels_in_grid": len(chairs),
        "probe_classes": [labels.names[c] if c != semmap.EMPTY_LABEL else None for c in probe_labels.tolist()],
        "probe_confidence": [round(float(c), 3) for c in probe_conf],
        "grid_agrees_on_floor": float(np.mean(grid_labels == labels.id_of("floor"))),
        "reloaded_map_answers_the_same": same,
        "map_file": str(path),
    }


def main() -> None:
    out = Path(sys.argv[1]) if len(sys.argv) > 1 else Path(tempfile.mkdtemp(prefix="semmap-api-"))
    out.mkdir(parents=True, exist_ok=True)
    for key, value in build_and_query(out).items():
        print(f"{key}: {value}")


if __name__ == "__main__":
    main()
