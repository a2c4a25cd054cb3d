"""2D navigation grids and semantic costmaps from an occupancy volume, for planners that read ROS map_server maps.

A cell of the grid is occupied when an occupied voxel lies in the robot's height band above the floor, free when
the band was seen free there (and nothing in it is occupied), unknown otherwise. Classes can be made no-go (lethal
at any height from the floor up to the band's top) or given a cost; an optional inflation radius marks the cells
a robot of that radius cannot enter.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy import ndimage

from semmap.errors import ConfigError
from semmap.products.occupancy import FREE, OCCUPIED, UNKNOWN, OccupancyVolume

LETHAL = 100  # map_server / nav2 cost of an obstacle
INSCRIBED = 99  # a cell closer to an obstacle than the robot's radius
FLOOR_NAMES = ("floor", "ground", "carpet", "rug")


@dataclass(frozen=True)
class GridOptions:
    """Height band above the floor (metres), the floor height (None: detected), class costs and inflation."""

    z_min: float = 0.1
    z_max: float = 1.5
    floor: float | None = None
    no_go: tuple[str, ...] = ()
    costs: dict[str, int] = field(default_factory=dict)
    inflation: float = 0.0

    def __post_init__(self) -> None:
        values = (self.z_min, self.z_max, self.inflation) + (() if self.floor is None else (self.floor,))
        if not all(np.isfinite(v) for v in values):
            raise ConfigError("--z-min, --z-max, --floor and --inflation must be finite numbers")
        if self.z_max <= self.z_min:
            raise ConfigError(f"--z-max ({self.z_max}) must be above --z-min ({self.z_min})")
        if not 0.0 <= self.inflation <= 10.0:
            raise ConfigError(f"--inflation must be between 0 and 10 m, got {self.inflation}")
        for name, cost in self.costs.items():
            if not 0 <= int(cost) <= LETHAL:
                raise ConfigError(f"--cost {name}={cost}: a cost is between 0 and {LETHAL}")


@dataclass(frozen=True)
class NavigationGrid:
    """Cell ``(i, j)`` has its lower-left corner at ``origin + (i, j) * resolution`` (x, y metres)."""

    occupancy: np.ndarray  # (nx, ny) int8: -1 unknown, 0 free, 100 occupied (obstacles and no-go classes)
    cost: np.ndarray  # (nx, ny) int8: -1 unknown, else 0..100 (class costs, inflation, lethal)
    origin: np.ndarray  # (2,) float64
    resolution: float
    floor_z: float
    band: tuple[float, float]  # absolute z of the band (metres)
    classes: dict[str, int]  # class name -> cells it marks (no-go and costed classes)


def _class_ids(volume: OccupancyVolume, names: tuple[str, ...] | list[str], option: str) -> dict[str, int]:
    if not names:
        return {}
    if volume.label_set is None:
        raise ConfigError(f"{option} names classes, but the map has no label set")
    known = {n.lower(): i for i, n in enumerate(volume.label_set.names)}
    missing = [n for n in names if n.lower() not in known]
    if missing:
        raise ConfigError(f"{option}: {', '.join(missing)} not in the map's classes ({', '.join(known)})")
    return {n: known[n.lower()] for n in names}


def detect_floor(volume: OccupancyVolume) -> float:
    """Floor height: the top of the voxels labelled floor when the label set has such a class, else of the lowest
    horizontal layer holding at least half as many occupied voxels as the fullest layer of the lower half."""
    occ = volume.state == OCCUPIED
    z_of = volume.origin[2] + np.arange(volume.shape[2]) * volume.resolution
    if volume.label_set is not None:
        ids = [i for i, n in enumerate(volume.label_set.names) if n.lower() in FLOOR_NAMES]
        floor = occ & np.isin(volume.labels, ids)
        if floor.sum() >= 10:
            layer = np.median(np.nonzero(floor)[2])
            return float(volume.origin[2] + layer * volume.resolution + volume.resolution / 2)
    per_layer = occ.sum(axis=(0, 1))
    if per_layer.sum() == 0:
        raise ConfigError("the map (within --region, when one is given) has no occupied voxel to find the floor on; "
                          "give --floor")
    lower = per_layer[: max(1, (len(per_layer) + 1) // 2)]
    layer = int(np.flatnonzero(lower >= 0.5 * lower.max())[0])
    return float(z_of[layer] + volume.resolution / 2)


def navigation_grid(volume: OccupancyVolume, options: GridOptions | None = None) -> NavigationGrid:
    """The 2D grid and costmap of ``volume`` (see the module docstring)."""
    o = options or GridOptions()
    floor = detect_floor(volume) if o.floor is None else float(o.floor)
    z = volume.origin[2] + np.arange(volume.shape[2]) * volume.resolution
    band = (z >= floor + o.z_min) & (z <= floor + o.z_max)
    if not band.any():
        raise ConfigError(f"the band {floor + o.z_min:.2f}..{floor + o.z_max:.2f} m (floor {floor:.2f} m) holds no "
                          f"voxel of the map ({z[0]:.2f}..{z[-1]:.2f} m); check --floor, --z-min and --z-max")
    s = volume.state[:, :, band]
    occupied = (s == OCCUPIED).any(axis=2)
    free = ~occupied & (s == FREE).any(axis=2)
    grid = np.full(occupied.shape, UNKNOWN, np.int8)
    grid[free] = FREE
    grid[occupied] = LETHAL
    cost = grid.copy()
    column = (z >= floor - volume.resolution) & (z <= floor + o.z_max)
    labels, occ3 = volume.labels[:, :, column], volume.state[:, :, column] == OCCUPIED
    marked: dict[str, int] = {}
    for name, cid in _class_ids(volume, o.no_go, "--no-go").items():
        cells = (occ3 & (labels == cid)).any(axis=2)
        grid[cells] = cost[cells] = LETHAL
        marked[name] = int(cells.sum())
    for name, cid in _class_ids(volume, list(o.costs), "--cost").items():
        cells = (occ3 & (labels == cid)).any(axis=2)
        cost[cells] = np.maximum(cost[cells], np.int8(o.costs[name]))
        marked[name] = int(cells.sum())
    if o.inflation > 0:
        near = ndimage.distance_transform_edt(grid != LETHAL) * volume.resolution <= o.inflation
        cost[near & (cost < INSCRIBED)] = INSCRIBED
    origin = volume.origin[:2] - volume.resolution / 2
    return NavigationGrid(grid, cost, origin, volume.resolution, floor,
                          (float(floor + o.z_min), float(floor + o.z_max)), marked)
