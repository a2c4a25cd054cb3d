"""Object-constrained camera poses: ``--poses X-objects`` (the object-oriented SLAM paper's Sec. 3.4, eqs. 19-22).

A tracker ``X`` runs as usual; beside it every frame's instances are detected and tracked (DeepSORT), and every
keyframe (10 cm or 10 degrees of camera motion) keeps its detections' filtered clouds in the camera frame. When
the trajectory is asked for, the keyframes are placed with X's final poses into an object map
(:class:`~semmap.maps.objects.ObjectMap`, eq. 22 association), which says which detections of two keyframes are
one object. For two keyframes a and b at least ``min_gap`` keyframes apart that share objects, each shared object
gives a pair of centroids: the centroids (eq. 16) of the parts of its two clouds that overlap (cells both hold),
each in its keyframe's camera frame; partial views of one object have different centroids, their overlapping
parts the same. A pair counts when eq. 22 says the two clouds are one object (track id, centroid distance,
overlap M of eq. 21). With three or more pairs not on a line, eq. 20 gives the relative pose in closed form and
it becomes an edge of the keyframe pose graph (:mod:`semmap.poses.object_graph`), its noise from the fit's
residuals. An edge that agrees with X's own relative pose within that noise says nothing new and is left out.

This module wires poses, perception and maps together (like ``pipeline.py``), so no stage imports another
against the flow.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from semmap.errors import ConfigError
from semmap.maps.objects import CameraClouds, ObjectMap, ObjectMapParams, Sighting, overlap_iou, pack_cells
from semmap.perception.instances.base import InstanceSource
from semmap.perception.instances.registry import INSTANCE_SOURCES
from semmap.perception.schedule import Scheduler, SegmentationSchedule
from semmap.perception.tracking import DeepSort
from semmap.poses.base import PoseTracker
from semmap.poses.object_graph import ObjectEdge, agrees, apply_corrections, fit_rigid, optimise_with_object_edges
from semmap.poses.track import OBJECT_METHODS, OBJECTS_SUFFIX, make_tracker
from semmap.types import Frame, Trajectory, invert_pose

#: Weight of the angle between two viewing directions against the distance of the cameras (metres per radian).
VIEW_METRES_PER_RADIAN = 0.5


@dataclass(frozen=True)
class ObjectPoseParams:
    """Settings of the object-constrained pose graph."""

    keyframe_distance: float = 0.10  #: metres of camera motion between keyframes
    keyframe_angle_deg: float = 10.0
    min_gap: int = 5  #: object edges only between keyframes at least this many keyframes apart
    edges_per_keyframe: int = 2  #: object edges a keyframe gets at most (to the keyframes of the closest views)
    min_objects: int = 3  #: centroid pairs an edge needs (eq. 20 needs three not on a line)
    min_spread: float = 0.05  #: metres; the pairs' second principal spread must exceed this (not on a line)
    min_overlap_points: int = 20  #: points each overlapping part needs for its centroid
    #: metres; cells that decide which parts of two clouds overlap (the voxel filter's: with 2 or 3 cm cells the
    #: edges' median error against the true relative pose was larger, see DESIGN)
    overlap_cell: float = 0.01
    #: metres; standard deviation of one overlap centroid at least (the fit's residuals of 3-5 pairs understate it:
    #: on the simulated loop the edges' median error was 1.1 cm, 7x what the residuals claimed)
    centroid_sigma_floor: float = 0.02
    odometry_sigma: tuple[float, float] = (0.005, 0.01)  #: radians, metres: the tracker's keyframe steps
    huber: float = 1.345  #: Huber threshold of object edges (in standard deviations)
    #: object edges that must disagree with the tracker before any is used: drift shows in every later keyframe's
    #: edges, a wrong association in one (the simulated walk's single edge of 49 raised slam-features' ATE 6.6 %)
    min_edges: int = 3
    object_map: ObjectMapParams = field(default_factory=ObjectMapParams)

    def __post_init__(self) -> None:
        if self.min_objects < 3:
            raise ConfigError("object pose edges need at least three centroid pairs (eq. 20)")
        if self.min_gap < 1 or self.edges_per_keyframe < 0:
            raise ConfigError("object poses: min_gap >= 1 and edges_per_keyframe >= 0")


@dataclass
class _Keyframe:
    index: int  # position of the frame in the tracked sequence
    name: str
    clouds: CameraClouds


@dataclass
class ObjectEdgeStats:
    """What the object constraints did (for reports and benchmarks)."""

    keyframes: int = 0
    candidate_edges: int = 0  #: keyframe pairs with enough shared objects
    agreeing_edges: int = 0  #: left out: the tracker already agrees within the edge's noise
    edges: int = 0  #: object edges in the optimised graph
    pairs_rejected: int = 0  #: shared objects whose two clouds failed eq. 22
    edges_ignored: int = 0  #: disagreeing edges left out because fewer than ``min_edges`` disagreed


class ObjectConstrainedTracker:
    """A :class:`~semmap.poses.base.PoseTracker` whose keyframe poses are corrected by object constraints."""

    def __init__(self, base: PoseTracker, source: InstanceSource, params: ObjectPoseParams | None = None) -> None:
        self.base = base
        self.source = source
        self.params = ObjectPoseParams() if params is None else params
        self.name = f"{base.name}-objects"
        self.tracker = DeepSort(num_classes=len(source.label_set))
        self._extractor = ObjectMap(source.label_set, self.params.object_map)
        self._keyframe_of = Scheduler(SegmentationSchedule(keyframes=True,
                                                           min_translation=self.params.keyframe_distance,
                                                           min_rotation_deg=self.params.keyframe_angle_deg))
        self._keyframes: list[_Keyframe] = []
        self._frames = 0
        self.stats = ObjectEdgeStats()
        self.object_map: ObjectMap | None = None

    def track(self, frame: Frame) -> np.ndarray | None:
        """The base tracker's pose; detections are tracked on every frame and kept on keyframes."""
        T = self.base.track(frame)
        index = self._frames
        self._frames += 1
        instances = self.tracker.update(self.source.detect(frame), frame, T)
        if T is not None and self._keyframe_of.due(T):
            clouds = self._extractor.extract(instances, frame.depth, frame.rgb, frame.intrinsics)
            self._keyframes.append(_Keyframe(index, frame.name, clouds))
        return T

    def trajectory(self) -> Trajectory:
        """The base tracker's trajectory corrected by the object-constrained keyframe pose graph."""
        base = self.base.trajectory()
        pose_of = dict(zip(base.names, base.poses, strict=True))
        kfs = [k for k in self._keyframes if k.name in pose_of]
        self.stats = ObjectEdgeStats(keyframes=len(kfs))
        if len(kfs) < self.params.min_gap + 1:
            return base
        T_kf = np.array([pose_of[k.name] for k in kfs])
        edges = self._object_edges(kfs, T_kf)
        if len(edges) < self.params.min_edges:  # a lone disagreeing edge among agreeing ones is an outlier
            self.stats.edges_ignored = len(edges)
            self.stats.edges = 0
            return base
        optimised = optimise_with_object_edges(T_kf, edges, odometry_sigma=self.params.odometry_sigma,
                                               huber=self.params.huber)
        return apply_corrections(base, [k.name for k in kfs], T_kf, optimised)

    # ------------------------------------------------------------------ object edges
    def _object_edges(self, kfs: list[_Keyframe], T_kf: np.ndarray) -> list[ObjectEdge]:
        """Edges between keyframes from their shared objects' overlapping parts (eq. 20)."""
        p = self.params
        omap = ObjectMap(self.source.label_set, p.object_map)
        self.object_map = omap
        placed = []  # per keyframe: {object id: (sighting points_cam, cells, track id)}
        for k, T in zip(kfs, T_kf, strict=True):
            sightings = omap.place(k.clouds, T)
            ids = omap.integrate_clouds(k.clouds, T, k.index)
            placed.append({int(ids[s.detection]): s for s in sightings if ids[s.detection] > 0})
        placed = [{omap.resolve(o): s for o, s in d.items()} for d in placed]
        edges = []
        for b in range(len(kfs)):
            partners = [a for a in range(b - p.min_gap + 1)
                        if len(placed[a].keys() & placed[b].keys()) >= p.min_objects]
            chosen = _closest_views(partners, T_kf, b, p.edges_per_keyframe)
            for a in chosen:
                self.stats.candidate_edges += 1
                edge = self._edge(placed[a], placed[b], T_kf[a], T_kf[b], omap)
                if edge is None:
                    continue
                T_ab, sig = edge
                if agrees(invert_pose(T_kf[a]) @ T_kf[b], T_ab, sig):
                    self.stats.agreeing_edges += 1
                    continue
                edges.append(ObjectEdge(a, b, T_ab, sig))
        self.stats.edges = len(edges)
        return edges

    def _edge(self, seen_a: dict, seen_b: dict, T_a: np.ndarray, T_b: np.ndarray,
              omap: ObjectMap) -> tuple[np.ndarray, np.ndarray] | None:
        """Eq. 20 between keyframes a and b over their shared objects' overlapping parts: ``(T_a_b, sigmas)``."""
        p = self.params
        shared = []
        for o in seen_a.keys() & seen_b.keys():
            sa, sb = seen_a[o], seen_b[o]
            same = sa.track_id > 0 and sa.track_id == sb.track_id
            dist = float(np.linalg.norm(sa.centroid - sb.centroid))
            coarse_cell = p.object_map.merge_voxel
            coarse = overlap_iou(_coarse_cells(sa, coarse_cell), _coarse_cells(sb, coarse_cell))
            if omap.score(same, dist, max(overlap_iou(sa.cells, sb.cells), coarse)) <= p.object_map.score_threshold:
                self.stats.pairs_rejected += 1  # eq. 22 says these two clouds are not one object
                continue
            shared.append((sa.points_cam.astype(np.float64), sb.points_cam.astype(np.float64)))
        if len(shared) < p.min_objects:
            return None
        # the overlapping parts under the tracker's relative pose: b's points moved into a's frame, cells both hold
        T_ab = invert_pose(T_a) @ T_b
        cell = p.overlap_cell
        pa, pb = [], []
        for qa, qb in shared:
            ka = pack_cells(np.floor(qa / cell).astype(np.int64))
            kb = pack_cells(np.floor((qb @ T_ab[:3, :3].T + T_ab[:3, 3]) / cell).astype(np.int64))
            common = np.intersect1d(ka, kb)
            in_a, in_b = np.isin(ka, common), np.isin(kb, common)
            if in_a.sum() >= p.min_overlap_points and in_b.sum() >= p.min_overlap_points:
                pa.append(qa[in_a].mean(axis=0))  # eq. 16 over the overlapping part, each in its own camera
                pb.append(qb[in_b].mean(axis=0))
        if len(pa) < p.min_objects:
            return None
        pa, pb = np.array(pa), np.array(pb)
        T_ab = fit_rigid(pa, pb)  # eq. 20
        spread = np.linalg.svd(pa - pa.mean(axis=0), compute_uv=False)
        if spread[1] / np.sqrt(len(pa)) < p.min_spread:
            return None
        resid = pa - (pb @ T_ab[:3, :3].T + T_ab[:3, 3])
        dof = max(3 * len(pa) - 6, 1)
        sigma_pt = max(float(np.sqrt((resid**2).sum() / dof)), p.centroid_sigma_floor)
        sig_t = sigma_pt / np.sqrt(len(pa))
        radius = float(np.sqrt(((pa - pa.mean(axis=0)) ** 2).sum(axis=1).mean()))
        sig_r = sigma_pt / (radius * np.sqrt(len(pa)))
        return T_ab, np.array([sig_r] * 3 + [sig_t] * 3)



def _coarse_cells(s: Sighting, cell: float) -> np.ndarray:
    """Sorted unique cells of size ``cell`` a sighting's (world) points fall in."""
    return np.unique(pack_cells(np.floor(s.points.astype(np.float64) / cell).astype(np.int64)))


def _closest_views(candidates: list[int], T_kf: np.ndarray, b: int, k: int) -> list[int]:
    """The ``k`` candidate keyframes whose view is most like keyframe ``b``'s (camera distance plus 0.5 m per
    radian between the viewing directions): a revisit sees an object's same side, whose clouds overlap."""
    if k <= 0 or not candidates:
        return []
    c = np.asarray(candidates)
    dist = np.linalg.norm(T_kf[c, :3, 3] - T_kf[b, :3, 3], axis=1)
    cos = np.clip(np.einsum("ij,j->i", T_kf[c, :3, 2], T_kf[b, :3, 2]), -1.0, 1.0)
    order = np.argsort(dist + VIEW_METRES_PER_RADIAN * np.arccos(cos), kind="stable")
    return sorted(c[order[:k]].tolist())


def make_pose_tracker(method: str, *, instances: InstanceSource | None = None) -> PoseTracker:
    """The tracker ``method`` names: one of :data:`~semmap.poses.track.TRACKERS`, or ``X-objects``
    (:data:`~semmap.poses.track.OBJECT_METHODS`), which needs the run's instance source."""
    if method in OBJECT_METHODS:
        if instances is None:
            choices = INSTANCE_SOURCES.choices(sep="|")
            raise ConfigError(f"--poses {method} needs an instance source (--instances {choices})")
        return ObjectConstrainedTracker(make_tracker(method[: -len(OBJECTS_SUFFIX)]), instances)
    return make_tracker(method)
