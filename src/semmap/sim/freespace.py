"""2-D free-space map of a scene at walking height: clearance to walls and furniture, shortest paths.

Cells are free when they lie inside a room (or a doorway between rooms) and outside the footprint of every
object that reaches below :data:`OBSTACLE_TOP`; the clearance is the distance to the nearest non-free cell.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage, sparse
from scipy.sparse import csgraph

from semmap.errors import SimulationError
from semmap.sim.scene import Scene

#: Grid cell size (metres).
CELL = 0.05
#: Objects whose lowest point is above this height (ceiling lights) do not block walking.
OBSTACLE_TOP = 1.95
#: Extra path cost near obstacles: cost per metre = 1 + CLEARANCE_WEIGHT / clearance.
CLEARANCE_WEIGHT = 0.6


def part_boxes(scene: Scene) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned boxes (lo, hi), each (P, 3), of the convex parts all objects are made of."""
    if not scene.hulls:
        return np.zeros((0, 3)), np.zeros((0, 3))
    lo = np.array([v.min(0) for _, v in scene.hulls])
    hi = np.array([v.max(0) for _, v in scene.hulls])
    return lo, hi


class FreeSpace:
    """Clearance grid over the scene's rooms (x, y), with point lookups and shortest paths."""

    def __init__(self, scene: Scene, cell: float = CELL) -> None:
        self.cell = cell
        self.origin = scene.bounds_min[:2] - 2 * cell
        size = scene.bounds_max[:2] - scene.bounds_min[:2] + 4 * cell
        self.shape = (int(np.ceil(size[0] / cell)), int(np.ceil(size[1] / cell)))  # (nx, ny)
        xs = self.origin[0] + (np.arange(self.shape[0]) + 0.5) * cell
        ys = self.origin[1] + (np.arange(self.shape[1]) + 0.5) * cell
        gx, gy = np.meshgrid(xs, ys, indexing="ij")
        pts = np.stack([gx.ravel(), gy.ravel(), np.full(gx.size, 1.0)], 1)
        free = scene.inside_rooms(pts).reshape(self.shape)
        self.room_id = np.full(self.shape, -1, np.int32)
        for i, r in enumerate(scene.rooms):
            inside = (gx >= r.bounds_min[0]) & (gx <= r.bounds_max[0]) & (gy >= r.bounds_min[1]) & \
                     (gy <= r.bounds_max[1])
            self.room_id[inside] = i
        lo, hi = part_boxes(scene)
        for a, b in zip(lo, hi, strict=True):
            if a[2] > OBSTACLE_TOP:
                continue
            i0, j0 = np.floor((a[:2] - self.origin) / cell - 0.5).astype(int) + 1
            i1, j1 = np.floor((b[:2] - self.origin) / cell - 0.5).astype(int)
            free[max(i0, 0):max(i1 + 1, 0), max(j0, 0):max(j1 + 1, 0)] = False
        self.free = free
        self.clearance = ndimage.distance_transform_edt(free) * cell
        self._xs, self._ys = xs, ys

    def index(self, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Grid indices of (N, 2) points (clipped to the grid)."""
        ij = np.floor((np.atleast_2d(xy) - self.origin) / self.cell).astype(int)
        return np.clip(ij[:, 0], 0, self.shape[0] - 1), np.clip(ij[:, 1], 0, self.shape[1] - 1)

    def clearance_at(self, xy: np.ndarray) -> np.ndarray:
        """Clearance (metres) at (N, 2) points; 0 outside rooms or on furniture."""
        i, j = self.index(xy)
        return self.clearance[i, j]

    def cell_center(self, i: np.ndarray, j: np.ndarray) -> np.ndarray:
        return np.stack([self._xs[i], self._ys[j]], -1)

    def free_cells(self, min_clearance: float, room: int | None = None, within: np.ndarray | None = None) \
            -> np.ndarray:
        """(N, 2) centres of cells with at least ``min_clearance``, optionally only in ``room`` and where the
        boolean grid ``within`` is set; row-major order."""
        mask = self.clearance >= min_clearance
        if room is not None:
            mask &= self.room_id == room
        if within is not None:
            mask &= within
        i, j = np.nonzero(mask)
        return self.cell_center(i, j)

    def components(self, min_clearance: float) -> np.ndarray:
        """Connected regions (8-neighbourhood) of cells with at least ``min_clearance``; 0 = not free."""
        labels, _ = ndimage.label(self.clearance >= min_clearance, structure=np.ones((3, 3), bool))
        return labels

    def largest_region(self, min_clearance: float, room: int | None = None, through=None) -> np.ndarray:
        """Boolean grid of the connected free region with most cells in ``room`` (or the one containing the
        point ``through`` when given; empty when that point is not free)."""
        labels = self.components(min_clearance)
        if through is not None:
            (i,), (j,) = self.index(np.asarray(through)[None, :2])
            return labels == labels[i, j] if labels[i, j] > 0 else np.zeros(self.shape, bool)
        sel = labels[(labels > 0) & ((self.room_id == room) if room is not None else True)]
        if sel.size == 0:
            return np.zeros(self.shape, bool)
        return labels == int(np.argmax(np.bincount(sel)))

    def shortest_path(self, start: np.ndarray, goal: np.ndarray, min_clearance: float) -> np.ndarray:
        """(N, 2) cell centres of the cheapest 8-connected path between two points through cells with at least
        ``min_clearance``; raises SimulationError when there is none."""
        ok = self.clearance >= min_clearance
        node = -np.ones(self.shape, np.int64)
        node[ok] = np.arange(int(ok.sum()))
        rows, cols, weights = [], [], []
        cost = 1.0 + CLEARANCE_WEIGHT / np.maximum(self.clearance, self.cell)
        ia, ja = np.nonzero(ok)
        for di, dj in ((1, 0), (0, 1), (1, 1), (1, -1)):
            ib, jb = ia + di, ja + dj
            inb = (ib < self.shape[0]) & (jb >= 0) & (jb < self.shape[1])
            a_i, a_j, b_i, b_j = ia[inb], ja[inb], ib[inb], jb[inb]
            keep = ok[b_i, b_j]
            a_i, a_j, b_i, b_j = a_i[keep], a_j[keep], b_i[keep], b_j[keep]
            w = self.cell * float(np.hypot(di, dj)) * 0.5 * (cost[a_i, a_j] + cost[b_i, b_j])
            rows += [node[a_i, a_j], node[b_i, b_j]]
            cols += [node[b_i, b_j], node[a_i, a_j]]
            weights += [w, w]
        n = int(ok.sum())
        graph = sparse.csr_matrix((np.concatenate(weights), (np.concatenate(rows), np.concatenate(cols))),
                                  shape=(n, n))
        (si,), (sj,) = self.index(start)
        (gi,), (gj,) = self.index(goal)
        if node[si, sj] < 0 or node[gi, gj] < 0:
            raise SimulationError("path start or goal is not in free space")
        _, pred = csgraph.dijkstra(graph, indices=int(node[si, sj]), return_predecessors=True)
        cells = np.argwhere(ok)  # row-major, matches node numbering
        path = [int(node[gi, gj])]
        while path[-1] != node[si, sj]:
            p = int(pred[path[-1]])
            if p < 0:
                raise SimulationError("no collision-free path between the requested points")
            path.append(p)
        idx = cells[np.array(path[::-1])]
        return self.cell_center(idx[:, 0], idx[:, 1])
