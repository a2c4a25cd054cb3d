"""Rooms as a 2D label image: from the simulator's layout in simulation, or from a room segmentation of a map's
navigation grid on real data.

The segmentation: free cells farther than half a door's width from any obstacle or unknown cell are room cores
(a door is too narrow to hold one, so the cores of two rooms do not touch); connected cores larger than
``min_area`` are the rooms; every other known cell (free or occupied: furniture stands in a room) joins the core
nearest to it. This is the distance-transform
segmentation of Bormann et al. 2016 ("Room segmentation: survey, implementation, and analysis") in its simplest form.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from semmap.products.navgrid import NavigationGrid


@dataclass(frozen=True)
class RoomMap:
    """``labels[i, j]`` is the room of the cell with lower-left corner ``origin + (i, j) * resolution`` (-1: none)."""

    labels: np.ndarray  # (nx, ny) int32
    origin: np.ndarray  # (2,) float64
    resolution: float
    names: tuple[str, ...]
    floor_z: float = 0.0
    source: str = "grid"

    def room_at(self, xy: np.ndarray) -> np.ndarray:
        """(N,) room index of each (N, 2) point (-1 outside every room)."""
        ij = np.floor((np.asarray(xy, np.float64).reshape(-1, 2) - self.origin) / self.resolution).astype(np.int64)
        inside = np.all((ij >= 0) & (ij < np.array(self.labels.shape)), axis=1)
        out = np.full(len(ij), -1, np.int32)
        out[inside] = self.labels[ij[inside, 0], ij[inside, 1]]
        return out

    def footprint(self, room: int) -> tuple[np.ndarray, np.ndarray, float]:
        """(centre xy, (min xy, max xy) as a (2, 2) array, area in m²) of a room."""
        ij = np.argwhere(self.labels == room)
        lo = self.origin + ij.min(axis=0) * self.resolution
        hi = self.origin + (ij.max(axis=0) + 1) * self.resolution
        centre = self.origin + (ij.mean(axis=0) + 0.5) * self.resolution
        return centre, np.stack([lo, hi]), float(len(ij) * self.resolution**2)


def rooms_from_grid(grid: NavigationGrid, *, door_width: float = 1.0, min_area: float = 1.0) -> RoomMap:
    """The room segmentation of a navigation grid (module docstring)."""
    free = grid.occupancy == 0
    clearance = ndimage.distance_transform_edt(free) * grid.resolution
    cores, n = ndimage.label(clearance > door_width / 2)
    sizes = ndimage.sum_labels(np.ones_like(cores), cores, index=np.arange(1, n + 1)) * grid.resolution**2
    keep = np.flatnonzero(sizes >= min_area) + 1
    core = np.where(np.isin(cores, keep), cores, 0)
    if not keep.size:
        return RoomMap(np.full(free.shape, -1, np.int32), grid.origin, grid.resolution, (), grid.floor_z)
    renumber = np.full(n + 1, -1, np.int32)
    renumber[keep] = np.arange(len(keep))
    nearest = ndimage.distance_transform_edt(core == 0, return_distances=False, return_indices=True)
    labels = renumber[core[nearest[0], nearest[1]]]
    labels[grid.occupancy < 0] = -1  # unknown space belongs to no room; walls and furniture to the nearest
    return RoomMap(labels.astype(np.int32), grid.origin, grid.resolution,
                   tuple(f"room {i}" for i in range(len(keep))), grid.floor_z)


def rooms_from_boxes(boxes: list[tuple[str, np.ndarray, np.ndarray]], resolution: float = 0.05) -> RoomMap:
    """Rooms given as named axis-aligned boxes (the simulator's layout: (name, min xyz, max xyz)), rasterised."""
    lo = np.min([b[1][:2] for b in boxes], axis=0)
    hi = np.max([b[2][:2] for b in boxes], axis=0)
    shape = np.ceil((hi - lo) / resolution).astype(int) + 1
    labels = np.full(shape, -1, np.int32)
    centres = lo + (np.indices(shape).transpose(1, 2, 0) + 0.5) * resolution
    for i, (_, bmin, bmax) in enumerate(boxes):
        inside = np.all((centres >= bmin[:2]) & (centres <= bmax[:2]), axis=-1)
        labels[inside & (labels < 0)] = i
    floor = float(min(b[1][2] for b in boxes))
    return RoomMap(labels, lo, resolution, tuple(b[0] for b in boxes), floor, source="layout")
