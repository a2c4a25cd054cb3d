"""The semantic mesh: the TSDF's marching-cubes surface with, per vertex, the colour, class, confidence and class
distribution of the semantic map's voxel it lies in.

A vertex takes the occupied voxel of the semantic map (the run's OctoMap or grid, else the TSDF's own voxel grid)
that holds it, as :meth:`~semmap.maps.base.SemanticMap.class_at` reads it; where that voxel is not occupied, the
occupied voxel among its 26 neighbours whose centre is nearest to the vertex; with neither it has no class
(``EMPTY_LABEL``, confidence 0) and the TSDF's own colour at it.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from semmap.keys import coords_to_keys, index_in, keys_to_coords, pack_keys
from semmap.maps.base import SemanticMap
from semmap.types import EMPTY_LABEL, LabelSet

#: Colour of vertices no voxel colours.
UNCOLOURED = 128
#: The 26 neighbours of a voxel, as key offsets.
NEIGHBOURS = np.array([(i, j, k) for i in (-1, 0, 1) for j in (-1, 0, 1) for k in (-1, 0, 1) if i or j or k],
                      np.int64)


@dataclass(frozen=True)
class SemanticMesh:
    """A triangle mesh with per-vertex colour and classes (``probs`` (V, K) when the map has a label set)."""

    vertices: np.ndarray  # (V, 3) float32 world metres
    faces: np.ndarray  # (F, 3) int32 vertex indices, counter-clockwise seen from the free side
    colors: np.ndarray  # (V, 3) uint8
    labels: np.ndarray  # (V,) uint16, EMPTY_LABEL where no occupied voxel holds or neighbours the vertex
    confidence: np.ndarray  # (V,) float32 probability of that class (0 where none)
    probs: np.ndarray | None  # (V, K) float32 class distribution (zeros where no class)
    label_set: LabelSet | None
    resolution: float  # the TSDF's voxel
    own_voxel: np.ndarray  # (V,) bool: the class is that of the voxel holding the vertex (not a neighbour's)
    ms: float = 0.0  # milliseconds to extract and label it

    def __len__(self) -> int:
        return int(self.vertices.shape[0])


def _sorted_keys(m: SemanticMap, cloud=None) -> tuple[np.ndarray, np.ndarray, object]:
    """The packed keys of ``m``'s occupied voxels sorted, their order into :meth:`cloud` (``cloud``: that cloud,
    when the caller has it already), and the cloud."""
    cloud = m.cloud() if cloud is None else cloud
    packed = pack_keys(coords_to_keys(cloud.centers, m.resolution))
    if np.all(packed[1:] > packed[:-1]):  # most maps list their voxels sorted by key already
        return packed, np.arange(len(packed)), cloud
    order = np.argsort(packed, kind="stable")
    return packed[order], order, cloud


def voxel_of_vertex(vertices: np.ndarray, m: SemanticMap, cloud=None) -> tuple[np.ndarray, np.ndarray]:
    """Index into ``m.cloud()`` (``cloud``: that cloud, already made) of the occupied voxel each vertex takes its
    class from (-1: none), and whether it is the voxel holding the vertex (else the nearest occupied one of its
    26 neighbours)."""
    sorted_packed, order, _ = _sorted_keys(m, cloud)
    if len(sorted_packed) == 0:
        return np.full(len(vertices), -1, np.int64), np.zeros(len(vertices), bool)
    keys = coords_to_keys(vertices, m.resolution)
    idx = index_in(sorted_packed, pack_keys(keys))
    own = idx >= 0
    todo = np.flatnonzero(~own)
    best = np.full(len(todo), -1, np.int64)
    best_d = np.full(len(todo), np.inf)
    for off in NEIGHBOURS:
        nk = keys[todo] + off
        j = index_in(sorted_packed, pack_keys(nk))
        d = np.linalg.norm(keys_to_coords(nk, m.resolution) - vertices[todo], axis=1)
        better = (j >= 0) & (d < best_d)
        best[better], best_d[better] = j[better], d[better]
    idx[todo] = best
    return np.where(idx >= 0, order[np.maximum(idx, 0)], -1), own


def semantic_mesh(tsdf, source: SemanticMap | None = None, *, min_weight: int = 1) -> SemanticMesh:
    """The mesh of ``tsdf`` (a :class:`~semmap.maps.tsdf.TsdfMap`) labelled from ``source`` (default: the TSDF's
    own voxel grid)."""
    t = time.perf_counter()
    source = tsdf if source is None else source
    vertices, faces = tsdf.mesh(min_weight)
    v = vertices.astype(np.float64)
    cloud = source.cloud()
    idx, own = voxel_of_vertex(v, source, cloud)
    has = idx >= 0
    labels = np.full(len(v), EMPTY_LABEL, np.uint16)
    conf = np.zeros(len(v), np.float32)
    labels[has], conf[has] = cloud.labels[idx[has]], cloud.confidence[idx[has]]
    colors = np.full((len(v), 3), UNCOLOURED, np.uint8)
    colors[has] = cloud.colors[idx[has]]
    if source is not tsdf and not has.all():  # the rest coloured by the TSDF's own voxels
        rest = np.flatnonzero(~has)
        own_cloud = tsdf.cloud()
        j, _ = voxel_of_vertex(v[rest], tsdf, own_cloud)
        colors[rest[j >= 0]] = own_cloud.colors[j[j >= 0]]
    probs = None
    if source.label_set is not None:
        dense = source.class_probs()
        probs = np.zeros((len(v), dense.shape[1]), np.float32)
        probs[has] = dense[idx[has]]
    return SemanticMesh(vertices, faces, colors, labels, conf, probs, source.label_set, tsdf.resolution,
                        own & has, (time.perf_counter() - t) * 1e3)
