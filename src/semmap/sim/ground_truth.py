"""Ground-truth 3-D semantics of a scene: labelled surface voxels (OctoMap keys) and the object list.

Voxels come from dense, deterministic lattice sampling of every triangle (spacing at most a third of a voxel
along each triangle edge, so every voxel the surface crosses more than a sliver of is hit). Each sample is
weighted by its share of the triangle's area, so a voxel's class is the one with the largest surface area in
it (ties: the lower class id); its instance the largest-area instance of that class.

Keys follow OctoMap: ``key = floor(double(float32(coord)) * (1 / resolution)) + 32768`` per axis. A surface
lying exactly on a voxel boundary (the floor at z = 0, walls on round coordinates) is counted in the voxels
on both sides, because depth measured on it lands on either side by the last bit: each sample is taken
``BOUNDARY_EPS`` in front of and behind its surface along the normal.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from semmap.errors import SimulationError
from semmap.keys import coords_to_keys, index_in, pack_keys, unpack_keys
from semmap.limits import BYTES_PER_GROUND_TRUTH_VOXEL, check_memory
from semmap.sim.scene import Scene, SceneObject

#: Lattice spacing = resolution / SAMPLES_PER_VOXEL.
SAMPLES_PER_VOXEL = 3
#: Offset (metres) of each sample in front of and behind its surface (see the module docstring).
BOUNDARY_EPS = 1e-4
#: Samples generated per batch (bounds memory).
BATCH = 2_000_000
_SEG_BITS = 15


@dataclass(frozen=True)
class GroundTruthVoxels:
    """Labelled surface voxels: ``keys`` (M, 3) int32 OctoMap keys, ``class_ids`` (M,) uint16,
    ``instance_ids`` (M,) int32 (0 for wall/floor/ceiling), sorted by packed key."""

    resolution: float
    keys: np.ndarray
    class_ids: np.ndarray
    instance_ids: np.ndarray

    def __len__(self) -> int:
        return len(self.keys)

    @property
    def packed(self) -> np.ndarray:
        """Keys packed as ``x | y << 16 | z << 32`` (int64), ascending."""
        return pack_keys(self.keys)

    def lookup(self, keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(class ids, instance ids) of (N, 3) keys; 0 / 0 where the voxel is not a surface voxel."""
        pos = index_in(self.packed, pack_keys(np.asarray(keys)))
        hit = pos >= 0
        cls = np.zeros(len(pos), np.uint16)
        inst = np.zeros(len(pos), np.int32)
        cls[hit], inst[hit] = self.class_ids[pos[hit]], self.instance_ids[pos[hit]]
        return cls, inst


def gt_objects(scene: Scene) -> list[SceneObject]:
    """The scene's object instances (ids, class, surface centroid, bounding box)."""
    return list(scene.objects)


def gt_voxels(scene: Scene, resolution: float) -> GroundTruthVoxels:
    """Surface voxels of ``scene`` at ``resolution`` metres with majority (by area) class and instance."""
    if not resolution > 0:
        raise SimulationError(f"voxel resolution must be positive, got {resolution}")
    V = scene.vertices.astype(np.float64)
    F = scene.triangles
    e1, e2 = V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]
    cross = np.cross(e1, e2)
    area = 0.5 * np.linalg.norm(cross, axis=1)
    normal = cross / np.maximum(2 * area, 1e-30)[:, None]
    longest = np.max(np.stack([np.linalg.norm(e1, axis=1), np.linalg.norm(e2, axis=1),
                               np.linalg.norm(e2 - e1, axis=1)], 1), axis=1)
    surface_voxels = 2 * float(area.sum()) / resolution**2  # (a voxel on either side of a surface)
    check_memory(f"--resolution {resolution:g} over the simulated scene's {float(area.sum()):,.0f} m² of surface "
                 f"(about {surface_voxels:,.0f} ground-truth voxels)", surface_voxels * BYTES_PER_GROUND_TRUTH_VOXEL)
    n_div = np.maximum(1, np.ceil(longest * SAMPLES_PER_VOXEL / resolution)).astype(np.int64)
    pairs = np.stack([scene.tri_class.astype(np.int64), scene.tri_instance.astype(np.int64)], 1)
    seg_pairs, seg_of_tri = np.unique(pairs, axis=0, return_inverse=True)
    if len(seg_pairs) >= 1 << _SEG_BITS:
        raise SimulationError("too many (class, instance) pairs for ground-truth voxelisation")
    seg_of_tri = seg_of_tri.reshape(-1)

    chunks_key: list[np.ndarray] = []
    chunks_w: list[np.ndarray] = []
    valid = area > 0
    for n in np.unique(n_div[valid]):
        tris = np.nonzero(valid & (n_div == n))[0]
        i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
        keep = i + j <= n
        a = (i[keep] / n).astype(np.float64)
        b = (j[keep] / n).astype(np.float64)
        per_batch = max(1, BATCH // len(a))
        for s in range(0, len(tris), per_batch):
            t = tris[s:s + per_batch]
            pts = V[F[t, 0]][:, None, :] + a[None, :, None] * e1[t][:, None, :] + b[None, :, None] * e2[t][:, None, :]
            w = np.repeat(area[t] / len(a), len(a))
            seg = np.repeat(seg_of_tri[t], len(a))
            off = BOUNDARY_EPS * normal[t][:, None, :]
            k_front = pack_keys(coords_to_keys((pts + off).reshape(-1, 3), resolution))
            k_back = pack_keys(coords_to_keys((pts - off).reshape(-1, 3), resolution))
            both = k_back != k_front
            packed = np.concatenate([k_front, k_back[both]]) << _SEG_BITS | np.concatenate([seg, seg[both]])
            u, inv = np.unique(packed, return_inverse=True)
            chunks_key.append(u)
            chunks_w.append(np.bincount(inv.reshape(-1), weights=np.concatenate([w, w[both]])))
    if not chunks_key:
        empty = np.zeros((0, 3), np.int32)
        return GroundTruthVoxels(resolution, empty, np.zeros(0, np.uint16), np.zeros(0, np.int32))
    u, inv = np.unique(np.concatenate(chunks_key), return_inverse=True)
    weight = np.bincount(inv.reshape(-1), weights=np.concatenate(chunks_w))
    return _majority(u, weight, seg_pairs, resolution)


def _majority(packed: np.ndarray, weight: np.ndarray, seg_pairs: np.ndarray, resolution: float) \
        -> GroundTruthVoxels:
    """Per voxel: the class with the largest weight (ties: lower id), then that class's heaviest instance."""
    key = packed >> _SEG_BITS
    seg = packed & ((1 << _SEG_BITS) - 1)
    cls = seg_pairs[seg, 0]
    inst = seg_pairs[seg, 1]
    # class weight per voxel
    kc, kc_inv = np.unique(key << 8 | cls, return_inverse=True)
    kc_w = np.bincount(kc_inv.reshape(-1), weights=weight)
    kc_key, kc_cls = kc >> 8, kc & 0xFF
    order = np.lexsort((kc_cls, -kc_w, kc_key))
    first = np.ones(len(order), bool)
    first[1:] = kc_key[order][1:] != kc_key[order][:-1]
    win_key = kc_key[order][first]
    win_cls = kc_cls[order][first]
    # heaviest instance of the winning class
    pos = np.searchsorted(win_key, key)
    of_winner = win_cls[pos] == cls
    k2, i2, w2 = key[of_winner], inst[of_winner], weight[of_winner]
    order = np.lexsort((i2, -w2, k2))
    first = np.ones(len(order), bool)
    first[1:] = k2[order][1:] != k2[order][:-1]
    win_inst = i2[order][first]
    return GroundTruthVoxels(resolution, unpack_keys(win_key).astype(np.int32), win_cls.astype(np.uint16),
                             win_inst.astype(np.int32))
