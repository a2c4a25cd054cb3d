"""The semantic point map of *rgbd-semantic-mapping-multiscale-crf* / *object-oriented-semantic-slam*.

Points voxel-filtered at a fine resolution (1 cm by default): each filter cell keeps one point, the mean of the
points that fell in it, with its mean colour, a normal (the mean of the pixels' depth-image normals) and a
fused class distribution (``bayes-prior``, eqs. 3-5, by default).  Like those systems it is updated on
keyframes only: other frames are skipped (:attr:`~semmap.types.Observation.keyframe`).
"""

from __future__ import annotations

import numpy as np

from semmap.fusion.rules import FusionParams, FusionRule
from semmap.maps.base import MapState, check_state
from semmap.maps.registry import MapKind
from semmap.maps.semantic_grid import OnSemanticGrid, SemanticGrid
from semmap.maps.voxel_grid import UNCOLOURED
from semmap.types import LabelSet, MapCloud, Observation

#: Default filter cell of the point map (metres).
DEFAULT_POINT_RESOLUTION = 0.01


class SemanticPointMap(OnSemanticGrid):
    """Voxel-filtered semantic points updated on keyframes; implements :class:`~semmap.maps.base.SemanticMap`."""

    kind = MapKind.POINTS
    needs_normals = True

    def __init__(self, resolution: float = DEFAULT_POINT_RESOLUTION, *, label_set: LabelSet | None = None,
                 fusion: FusionParams | None = None, dtype: str = "float16", keyframes_only: bool = True) -> None:
        self.grid = SemanticGrid(resolution, label_set=label_set,
                                 fusion=fusion or FusionParams(FusionRule.BAYES_PRIOR), dtype=dtype,
                                 keep_geometry=True)
        self.keyframes_only = keyframes_only
        self.frames_integrated = 0

    def integrate(self, obs: Observation) -> dict[str, float]:
        """Fuse a keyframe's points (other frames are skipped when ``keyframes_only``)."""
        if self.keyframes_only and not obs.keyframe:
            return {}
        self.frames_integrated += 1
        return self.grid.integrate_points(obs.points_world, colors=obs.colors, semantics=obs.semantics,
                                          normals=obs.normals)

    def cloud(self) -> MapCloud:
        """Every point: mean position, colour, top class, confidence and unit normal (zero where unknown)."""
        a = self.grid.arrays()
        labels, conf, _ = self.grid.summary(a)
        colors = np.where(a.rgb_count[:, None] > 0, a.rgb, np.uint8(UNCOLOURED)).astype(np.uint8)
        n = np.linalg.norm(a.normal_sums, axis=1, keepdims=True)
        normals = np.where(n > 0, a.normal_sums / np.where(n > 0, n, 1.0), 0.0).astype(np.float32)
        return MapCloud(a.positions.astype(np.float64), colors, labels, conf, self.resolution, normals)

    def class_at(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Most probable class and its probability of the filter cell holding each (N, 3) world point (its point's
        class in :meth:`cloud`); EMPTY_LABEL and 0 where the map has no point in that cell."""
        return self.grid.class_at(points)

    def class_probs(self) -> np.ndarray:
        """(M, K) class distribution of each point, in :meth:`cloud` order."""
        return self.grid.class_probs(self.grid.arrays())

    def points_per_view(self) -> np.ndarray:
        """(M,) measurements each point's distribution sums per view, in :meth:`cloud` order
        (:meth:`SemanticGrid.points_per_view`)."""
        return self.grid.points_per_view(self.grid.arrays())

    def class_probs_per_view(self) -> np.ndarray:
        """(M, K) distributions weighing each view once (what the CRF reads), in :meth:`cloud` order."""
        return self.grid.class_probs_per_view(self.grid.arrays())

    def set_class_probs(self, probs: np.ndarray, *, where: np.ndarray | None = None) -> None:
        """Replace the points' distributions (:meth:`cloud` order; only rows ``where`` is True)."""
        packed = self.grid.arrays().packed
        sel = np.ones(len(packed), bool) if where is None else np.asarray(where, bool)
        self.grid.set_class_probs(packed[sel], np.asarray(probs)[sel])

    def state(self) -> MapState:
        """The checkpoint state: the grid's and the frames integrated so far."""
        return {**self.grid.state(), "frames_integrated": np.int64(self.frames_integrated)}

    def restore(self, state: MapState) -> None:
        """Continue from :meth:`state` of a point map built with the same parameters."""
        check_state(state, ("frames_integrated",), "the point map")
        self.grid.restore(state)
        self.frames_integrated = int(state["frames_integrated"])

    def describe(self) -> dict:
        mem = self.grid.memory_bytes
        n = self.grid.num_voxels
        return {"points": n, "keyframes_integrated": self.frames_integrated, "fusion": self.fusion.name,
                "state_dtype": self.grid.dtype, "bytes_in_memory": mem,
                "bytes_per_voxel_in_memory": round(mem / max(n, 1), 2)}

    @property
    def memory_bytes(self) -> int:
        return self.grid.memory_bytes

    def __repr__(self) -> str:
        return (f"SemanticPointMap(resolution={self.resolution}, fusion={self.fusion.name}, "
                f"points={self.grid.num_voxels})")
