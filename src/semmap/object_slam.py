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
from scipy.spatial import cKDTree

from semmap.errors import ConfigError
from semmap.maps.objects import (
    CameraClouds,
    MaskView,
    ObjectMap,
    ObjectMapParams,
    Sighting,
    overlap_iou,
    pack_cells,
)
from semmap.perception.instances.base import InstanceSource
from semmap.perception.instances.registry import INSTANCE_SOURCES
from semmap.perception.schedule import Scheduler, SegmentationSchedule
from semmap.perception.tracking import DeepSort
from semmap.poses.base import PoseTracker
from semmap.poses.object_graph import (
    ObjectEdge,
    agrees,
    apply_corrections,
    fit_rigid,
    optimise_with_object_edges,
    plausible,
)
from semmap.poses.track import OBJECT_METHODS, OBJECTS_SUFFIX, make_tracker
from semmap.types import CameraIntrinsics, Frame, Trajectory, invert_pose

#: Matched points of two views must have surface normals within this cosine (about 30 degrees).
MIN_NORMAL_COSINE = 0.87
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
    min_overlap_points: int = 20  #: matched points an object needs to count in an edge
    #: metres; ICP's match distance, shrinking over the iterations (the first takes a few cm of drift)
    icp_distances: tuple[float, ...] = (0.05, 0.03, 0.02)
    icp_iterations: int = 30
    #: when the tracker's relative pose leaves fewer than ``min_objects`` overlapping parts, find the overlap under
    #: the whole clouds' centroid fit instead (a drift beyond a cell)
    drift_search: bool = True
    #: metres; a whole-cloud centroid pair further than this from the others' fit is left out of the edge
    max_residual: float = 0.05
    #: metres; standard deviation of one overlap centroid at least (the fit's residuals of 3-5 pairs understate it:
    #: on the simulated loop the edges' median error was 1.1 cm, 7x what the residuals claimed)
    centroid_sigma_floor: float = 0.02
    odometry_sigma: tuple[float, float] = (0.005, 0.01)  #: radians, metres: the tracker's keyframe steps
    huber: float = 1.345  #: Huber threshold of object edges (in standard deviations)
    #: object edges that must disagree with the tracker before any is used: drift shows in every later keyframe's
    #: edges, a wrong association in one (the simulated walk's single edge of 49 raised slam-features' ATE 6.6 %)
    min_edges: int = 3
    #: once ``min_edges`` edges disagree (the tracker drifted), the agreeing edges join the graph too: left out,
    #: the graph would hold only the edges that disagree, among which the worst registrations gather
    keep_agreeing: bool = True
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
    #: the detections' masks (detection + 1 per pixel) and the depth image, for the object map's mask check
    #: (maps.objects step 7) when the map is rebuilt with the final poses; None without the check
    masks: tuple[np.ndarray, np.ndarray, CameraIntrinsics] | None = None


@dataclass
class ObjectEdgeStats:
    """What the object constraints did (for reports and benchmarks)."""

    keyframes: int = 0
    candidate_edges: int = 0  #: keyframe pairs with enough shared objects
    agreeing_edges: int = 0  #: the tracker already agrees within the edge's noise (used only with disagreeing ones)
    disagreeing_edges: int = 0  #: the tracker disagrees beyond the edge's noise: drift, or a wrong registration
    edges: int = 0  #: object edges in the optimised graph
    pairs_rejected: int = 0  #: shared objects whose two clouds failed eq. 22
    edges_ignored: int = 0  #: disagreeing edges left out because fewer than ``min_edges`` disagreed
    #: why candidate keyframe pairs gave no edge, with counts: ``few_pairs`` (fewer than ``min_objects`` shared
    #: objects passed eq. 22), ``little_overlap`` (fewer than ``min_objects`` overlapping parts of
    #: ``min_overlap_points``), ``inconsistent`` (no ``min_objects`` centroid pairs agree on one rigid motion),
    #: ``on_a_line`` (the centroids' spread below ``min_spread``), ``implausible`` (farther from the tracker than
    #: its drift over the keyframe steps between them plus the edge's noise explains, 99.9 %)
    rejected: dict[str, int] = field(default_factory=dict)

    def reject(self, reason: str) -> None:
        """Count one candidate edge left out for ``reason``."""
        self.rejected[reason] = self.rejected.get(reason, 0) + 1


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
            masks = None
            if self.params.object_map.mask_check:
                ids = np.asarray(instances.ids)
                # 0.9 MB a 640x480 keyframe: half-precision depth is good to 2 mm at 4 m, the check's tolerance 3 cm
                masks = (ids.astype(np.uint8 if clouds.n < 255 else np.int32),
                         np.asarray(frame.depth, np.float16), frame.intrinsics)
            self._keyframes.append(_Keyframe(index, frame.name, clouds, masks))
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
        edges, agreeing = self._object_edges(kfs, T_kf)
        if len(edges) < self.params.min_edges:  # a lone disagreeing edge among agreeing ones is an outlier
            self.stats.edges_ignored = len(edges)
            self.stats.edges = 0
            return base
        if self.params.keep_agreeing:
            edges = edges + agreeing
            self.stats.edges = len(edges)
        optimised = optimise_with_object_edges(T_kf, edges, odometry_sigma=self.params.odometry_sigma,
                                               huber=self.params.huber)
        return apply_corrections(base, [k.name for k in kfs], T_kf, optimised)

    # ------------------------------------------------------------------ object edges
    def _object_edges(self, kfs: list[_Keyframe], T_kf: np.ndarray) -> tuple[list[ObjectEdge], list[ObjectEdge]]:
        """Edges between keyframes from their shared objects (eq. 20): those that disagree with the tracker, and
        those that agree with it."""
        p = self.params
        omap = ObjectMap(self.source.label_set, p.object_map)
        self.object_map = omap
        placed = []  # per keyframe: {object id: (sighting points_cam, cells, track id)}
        for k, T in zip(kfs, T_kf, strict=True):
            sightings = omap.place(k.clouds, T)
            view = None if k.masks is None else MaskView(*k.masks[:3], np.asarray(T, np.float64), k.clouds.n)
            ids = omap.integrate_clouds(k.clouds, T, k.index, view=view)
            placed.append({int(ids[s.detection]): s for s in sightings if ids[s.detection] > 0})
        placed = [{omap.resolve(o): s for o, s in d.items()} for d in placed]
        edges, agreeing = [], []
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
                tracked = invert_pose(T_kf[a]) @ T_kf[b]
                if not plausible(tracked, T_ab, sig, b - a, p.odometry_sigma):
                    self.stats.reject("implausible")
                    continue
                if agrees(tracked, T_ab, sig):
                    self.stats.agreeing_edges += 1
                    agreeing.append(ObjectEdge(a, b, T_ab, sig))
                    continue
                edges.append(ObjectEdge(a, b, T_ab, sig))
        self.stats.edges = self.stats.disagreeing_edges = len(edges)
        return edges, agreeing

    def _edge(self, seen_a: dict, seen_b: dict, T_a: np.ndarray, T_b: np.ndarray,
              omap: ObjectMap) -> tuple[np.ndarray, np.ndarray] | None:
        """Eq. 20 between keyframes a and b over their shared objects: ``(T_a_b, sigmas)``.

        The pairs eq. 22 calls one object (under the tracker's relative pose; when that leaves fewer than
        ``min_objects`` and ``drift_search`` is on, under the fit of the whole clouds' centroids, the pairs that
        agree on one rigid motion: a drift beyond the overlap cells) are registered by eq. 20 over their points,
        the ICP the paper names, each point matched only within its own object (:func:`_object_icp`)."""
        p = self.params
        pairs = [(seen_a[o], seen_b[o]) for o in sorted(seen_a.keys() & seen_b.keys())]
        T_ab = invert_pose(T_a) @ T_b
        same = [(sa, sb) for sa, sb in pairs if self._one_object(sa, sb, T_ab, omap)]
        if len(same) < p.min_objects and p.drift_search and len(pairs) >= p.min_objects:
            whole_a = np.array([sa.points_cam.mean(axis=0) for sa, _ in pairs], np.float64)
            whole_b = np.array([sb.points_cam.mean(axis=0) for _, sb in pairs], np.float64)
            T_whole, inliers = _robust_fit(whole_a, whole_b, p.max_residual, p.min_objects)
            if T_whole is None:
                self.stats.pairs_rejected += len(pairs) - len(same)
                self.stats.reject("inconsistent")
                return None
            T_ab, pairs = T_whole, [pairs[i] for i in inliers]
            same = [(sa, sb) for sa, sb in pairs if self._one_object(sa, sb, T_ab, omap)]
        self.stats.pairs_rejected += len(pairs) - len(same)
        if len(same) < p.min_objects:
            self.stats.reject("few_pairs")
            return None
        found = _object_icp(same, T_ab, p.icp_distances, p.icp_iterations, p.min_overlap_points)
        if found is None:
            self.stats.reject("little_overlap")
            return None
        T_ab, offsets, centres = found
        spread = np.linalg.svd(centres - centres.mean(axis=0), compute_uv=False)
        if len(centres) < p.min_objects or spread[1] / np.sqrt(len(centres)) < p.min_spread:
            self.stats.reject("on_a_line" if len(centres) >= p.min_objects else "little_overlap")
            return None
        dof = max(3 * len(offsets) - 6, 1)
        sigma_pt = max(float(np.sqrt((offsets**2).sum() / dof)), p.centroid_sigma_floor)
        sig_t = sigma_pt / np.sqrt(len(offsets))
        radius = float(np.sqrt(((centres - centres.mean(axis=0)) ** 2).sum(axis=1).mean()))
        sig_r = sigma_pt / (radius * np.sqrt(len(offsets)))
        return T_ab, np.array([sig_r] * 3 + [sig_t] * 3)

    def _one_object(self, sa: Sighting, sb: Sighting, T_ab: np.ndarray, omap: ObjectMap) -> bool:
        """Eq. 22 on two sightings with b's cloud moved into a's camera by ``T_ab``: track id, distance of the
        whole clouds' centroids (eq. 17) and overlap (eq. 21, at the overlap cell or the coarser merge cell)."""
        mp = self.params.object_map
        qa = sa.points_cam.astype(np.float64)
        qb = sb.points_cam.astype(np.float64) @ T_ab[:3, :3].T + T_ab[:3, 3]
        same = sa.track_id > 0 and sa.track_id == sb.track_id
        dist = float(np.linalg.norm(qa.mean(axis=0) - qb.mean(axis=0)))
        overlap = max(overlap_iou(_cells(qa, cell), _cells(qb, cell)) for cell in (mp.overlap_voxel, mp.merge_voxel))
        return omap.score(same, dist, overlap) > mp.score_threshold


def _cells(points: np.ndarray, cell: float) -> np.ndarray:
    """Sorted unique packed cells of size ``cell`` that ``points`` fall in."""
    return np.unique(pack_cells(np.floor(points / cell).astype(np.int64)))


def _object_icp(pairs: list[tuple[Sighting, Sighting]], T_ab: np.ndarray, distances: tuple[float, ...],
                iterations: int, min_points: int) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Eq. 20 over the points of shared objects from ``T_ab`` on (point-to-point ICP, b's points into a's
    camera): each point of b is matched to the nearest point of the same object in a, within a distance that
    shrinks through ``distances`` over the iterations. Returns the pose, each object's mean offset after it (its
    residual, as a centroid pair's) and a's matched parts' centroids; None when fewer than three objects have
    ``min_points`` matches."""
    qa = [sa.points_cam.astype(np.float64) for sa, _ in pairs]
    qb = [sb.points_cam.astype(np.float64) for _, sb in pairs]
    trees = [cKDTree(pa) for pa in qa]
    na = [_normals(pa, tree) for pa, tree in zip(qa, trees, strict=True)]
    nb = [_normals(pb, cKDTree(pb)) for pb in qb]
    T = T_ab
    for it in range(iterations):
        limit = distances[min(it * len(distances) // iterations, len(distances) - 1)]
        src, dst = [], []
        for tree, pa, pb, n_a, n_b in zip(trees, qa, qb, na, nb, strict=True):
            moved = pb @ T[:3, :3].T + T[:3, 3]
            d, idx = tree.query(moved, distance_upper_bound=limit)
            ok = np.isfinite(d)
            # a face one view sees and the other does not matches nothing: surfaces must face alike, and the
            # matches be mutual nearest neighbours
            ok[ok] = np.einsum("ij,ij->i", n_a[idx[ok]], n_b[ok] @ T[:3, :3].T) > MIN_NORMAL_COSINE
            if ok.any():
                back = cKDTree(moved).query(pa[idx[ok]])[1]
                ok[np.flatnonzero(ok)[back != np.flatnonzero(ok)]] = False
            if ok.sum() >= min_points:
                src.append(pb[ok])
                dst.append(pa[idx[ok]])
        if len(src) < 3:
            return None
        T = fit_rigid(np.vstack(dst), np.vstack(src))
    offsets = np.array([(a - (b @ T[:3, :3].T + T[:3, 3])).mean(axis=0) for a, b in zip(dst, src, strict=True)])
    return T, offsets, np.array([a.mean(axis=0) for a in dst])


def _normals(points: np.ndarray, tree: cKDTree, k: int = 8) -> np.ndarray:
    """(N, 3) unit surface normals of a camera-frame cloud (least-variance axis of each point's ``k`` nearest
    neighbours), turned towards the camera."""
    if len(points) < 3:
        return np.zeros_like(points)
    _, idx = tree.query(points, k=min(k, len(points)))
    nb = points[idx] - points[idx].mean(axis=1, keepdims=True)
    normals = np.linalg.eigh(np.einsum("nki,nkj->nij", nb, nb))[1][:, :, 0]
    return normals * -np.sign(np.einsum("ij,ij->i", normals, points))[:, None]


def _robust_fit(pa: np.ndarray, pb: np.ndarray, max_residual: float,
                min_pairs: int) -> tuple[np.ndarray | None, list[int]]:
    """Eq. 20 on centroid pairs, dropping the worst pair while its residual exceeds ``max_residual`` metres (a
    wrong association, or a part whose overlap is not yet found); ``(None, [])`` when fewer than ``min_pairs``
    pairs stay consistent."""
    idx = list(range(len(pa)))
    while len(idx) >= min_pairs:
        T = fit_rigid(pa[idx], pb[idx])
        resid = np.linalg.norm(pa[idx] - (pb[idx] @ T[:3, :3].T + T[:3, 3]), axis=1)
        worst = int(np.argmax(resid))
        if resid[worst] <= max_residual:
            return T, idx
        del idx[worst]
    return None, []


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
