"""The object-oriented map: one point cloud per object instance, with a class, a centroid and a history.

What *Multi-Objective Location and Mapping Based on Deep Learning and Visual SLAM* (Sec. 3.3-3.4) builds, per
keyframe and tracked detection (:class:`~semmap.types.Instances` with track ids):

1. the mask's pixels with depth are back-projected (every ``pixel_stride``-th row and column);
2. statistical outlier removal (eq. 18): a point whose mean distance to its neighbours exceeds ``t = m + k s``
   (mean and standard deviation of those distances over the detection) is dropped, which removes the depth of
   whatever a mask bled onto. The K-neighbourhood of a point is its (up to 8) neighbours on the depth image's
   pixel grid within the same mask, as for an organised cloud: one linear pass (``_object_kernels.py``) where a
   k-d tree over all mask points took 100 ms per keyframe;
3. the voxel filter keeps, per ``voxel`` cell, the point nearest the cell's centre;
4. association (eqs. 16-17, 21-22): the new cloud B belongs to an existing object A when the weighted score
   ``P = w . (P_ID, D, M)`` exceeds ``K``, with ``P_ID`` = 1 if A was seen under B's track id, ``D`` the centroid
   distance (eqs. 16-17; its term is ``1 - d / 0.1 m``, so only distances below the paper's 0.1 m count) and ``M``
   the overlap of eq. 21, ``AB / (A + B - AB)`` over cells of ``overlap_voxel``, between B and A's cloud of the
   keyframe A was last seen in (the paper's two images), or, when larger, the share of B's cells A already holds
   (a partial view of a part A has: a table's edge at the image border); its term is ``M / 0.8``, reaching 1
   at the paper's threshold. Objects of another class are candidates only through the track id. The detections of one
   keyframe are assigned one-to-one (``linear_sum_assignment`` on the scores), since two masks of one image are
   two objects; a sighting that holds most of two or more objects of its class (a mask that merged neighbours)
   is left out;
5. objects become real once their id appeared ``min_sightings`` times (the paper's three sightings against false
   detections): in the tracked frames (:meth:`ObjectMap.count_track_frames`), or in keyframes, and they were
   seen in ``min_keyframes`` keyframes;
6. objects that turn out to be one are merged: after each keyframe, the objects it touched are scored against their
   neighbours of the same class with the same ``P``, where for two accumulated clouds, which may each hold another
   side of the object, ``M`` is the share of the smaller cloud's cells the larger one has, at the overlap cell or at
   the coarser ``merge_voxel`` (the paper's octree of eq. 21, one level up), whichever is larger; two objects the
   segmenter told apart in the same keyframes (books side by side) are not merged by it. Two large objects
   (``MIN_COARSE_CELLS`` merge cells each) are merged, told apart or not, when most of the smaller's cells
   (``part_share``) lie within ``NEAR_CELLS`` cells (6 cm) of the larger's: one object seen in parts. A segmenter
   that cuts at depth jumps splits a chair seen from behind into its back and the seat below it, and a table into the
   pieces a chair in front leaves; from other sides the same mask covers the whole, so the whole's cloud already runs
   through the part's surface or its other face a chair back's thickness away. Two chairs 6 cm apart are near only
   along their facing sides (5-13 % of their cells in the tests, one chair's front and back 83-91 %), and books are
   too small for the rule;
7. the keyframe's own masks (:class:`MaskView`, when :meth:`ObjectMap.integrate` has the image) veto what the
   clouds alone would glue: an object whose points the camera sees (in the image, depth agreeing) mostly away
   from a detection's mask (farther than the detector's outline error, ``mask_outline_px``) is not that
   detection's object, and two objects whose visible points lie in different masks (or one in a mask, the other
   in none) are not merged. A book beside a missed or re-tracked neighbour shares its 3 cm cells and lies within
   10 cm of it, which eq. 22 alone takes for one object; the image tells them apart (objects a few outline
   errors wide in the image, ``min_width_outlines``, are left to eq. 22);
8. optionally (``window_sightings``, off: measured in docs/realism.md, it over-counts books on the living room
   and office walks), what the detector missed in a keyframe is taken from the frames before it: between
   keyframes :meth:`ObjectMap.note` keeps each track's latest detection cloud; at the keyframe, a kept cloud whose
   track the keyframe does not detect, and which the keyframe's camera sees (``min_visible_points``, depth
   agreeing) mostly in no mask, joins the keyframe as one more sighting. A detector that finds a thin book spine
   in half of the frames (its 2 px outline error halves a 5 px spine, under its 150 px minimum) would otherwise
   map it from one keyframe of the two to four that show it, and one keyframe is not enough (step 5).

Every object keeps score-weighted class votes, its cells, points and colours, track ids, sightings and the first
and last frame it was seen in; its centroid is the mean of its points (eq. 16).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from scipy.optimize import linear_sum_assignment

from semmap.errors import ConfigError
from semmap.geometry import pixel_rays
from semmap.maps._object_kernels import (
    cells_per_segment,
    grid_neighbour_distances,
    merge_cells,
    segment_bounds_and_mean,
    sorted_intersection_size,
    sorted_union,
)
from semmap.types import CameraIntrinsics, Instances, LabelSet

#: Cell keys are packed as three 21-bit signed fields: +-1e6 cells (10 km at 1 cm).
_KEY_BITS = 21
_KEY_OFFSET = 1 << (_KEY_BITS - 1)
_OUT_OF_RANGE = "object map: point coordinates out of range (more than a million cells from the origin)"
#: A sighting holding this share of each of two or more objects' last clouds merged them: it is left out.
SPAN_SHARE = 0.5
#: Objects must span this many merge cells each before their coarse overlap counts (a book spans two or three).
MIN_COARSE_CELLS = 8
#: Two objects detected apart in at least this many keyframes are never merged (unless one is a part of the other).
MIN_SEEN_APART = 1
#: Two objects are parts of one only where at least this share of one's cells lies within the other's bounds.
PART_REGION_SHARE = 0.25


@dataclass(frozen=True)
class ObjectMapParams:
    """Settings of :class:`ObjectMap` (paper values where it gives them: 0.1 m, 0.8, 3 sightings)."""

    voxel: float = 0.01  #: voxel filter cell (m)
    pixel_stride: int = 3  #: back-project every k-th mask pixel row and column (3: about the 1 cm cell at 1.5 m)
    min_depth: float = 0.1
    max_depth: float = 4.0  #: farther depth is too noisy for object clouds (m)
    sor_k: float = 1.0  #: k of eq. 18, t = m + k s
    min_points: int = 8  #: detections with fewer points after filtering are ignored
    centroid_distance: float = 0.1  #: eq. 17's threshold (m)
    overlap_voxel: float = 0.03  #: cell of the overlap test of eq. 21 (m)
    #: coarser cell (m) at which two accumulated objects' overlap is also measured when deciding a merge: two
    #: partial clouds of one desk, seen from its two sides, share few 3 cm cells but most 10 cm ones
    merge_voxel: float = 0.1
    overlap_threshold: float = 0.8  #: eq. 21's threshold
    weights: tuple[float, float, float] = (0.35, 0.25, 0.4)  #: w of eq. 22 for (P_ID, D, M)
    score_threshold: float = 0.33  #: K of eq. 22
    min_sightings: int = 3  #: frames an object's id must appear in before it is real (the paper's rule)
    #: ... and keyframes it must have been mapped from: a piece of a large object seen in one keyframe only
    #: (a table's corner at the image border, tracked for a few frames) is not another table
    min_keyframes: int = 2
    #: check association and merging against the keyframe's masks (:class:`MaskView`; step 7 of the module)
    mask_check: bool = True
    #: an object is a detection's only when at least this share of its visible points falls inside the mask ...
    mask_share: float = 0.5
    #: ... or within this many pixels of it (a detector's outline is that far off: the oracle's maskrcnn-like
    #: moves outlines by up to 2 px) ...
    mask_outline_px: int = 2
    #: ... judged when the camera sees at least this many of its points (fewer: out of view, eq. 22 decides) and
    #: they span at least this many outline errors across, both ways (narrower: a far book's 4 px spine, which an
    #: outline 2 px off cannot tell from its neighbour's; eq. 22 decides)
    min_visible_points: int = 10
    min_width_outlines: float = 4.0
    #: ... for objects at most this large (m, the longest side of their bounds): only neighbours within a few
    #: centroid distances of each other can be glued by eq. 22, and a large object's few visible points (its far
    #: side hidden) are too easily its mask's bleed onto the floor behind
    mask_check_max_size: float = 0.4
    #: two large objects are one when this share of the smaller's ``overlap_voxel`` cells lie within
    #: ``NEAR_CELLS`` of the larger's (step 6; above 1: never), even when seen apart in a keyframe: parts of one
    #: object that a segmenter cuts apart from some sides only (a chair's back and its seat where the back hides
    #: the seat's edge), and the sides of one table seen from opposite ends
    part_share: float = 0.8
    #: use the detections between keyframes where a keyframe's detector missed an object in view (step 8; off:
    #: on kinect it finds bedroom books but adds more books than it finds on the living room walk, docs/realism.md)
    window_sightings: bool = False
    #: ... for objects the keyframe shows with at least this many pixels (estimated from the kept cloud): one shown
    #: smaller than a detector's smallest mask (Mask R-CNN-like: 150 px) was not missed, only small
    window_min_pixels: int = 150

    def __post_init__(self) -> None:
        if min(self.voxel, self.overlap_voxel, self.centroid_distance, self.overlap_threshold) <= 0:
            raise ConfigError("object map: voxel, overlap_voxel, centroid_distance and overlap_threshold must be > 0")
        if self.pixel_stride < 1 or self.min_sightings < 1 or self.min_points < 1 or self.min_keyframes < 1:
            raise ConfigError("object map: pixel_stride, min_points and min_sightings must be >= 1")
        if not 0 <= self.min_depth < self.max_depth:
            raise ConfigError(f"object map: depth range [{self.min_depth}, {self.max_depth}] is empty")
        if not 0 <= self.mask_share <= 1 or self.min_visible_points < 1 or self.mask_outline_px < 0 or \
                self.min_width_outlines < 0:
            raise ConfigError(f"object map: mask_share {self.mask_share} must lie in [0, 1] and "
                              f"min_visible_points {self.min_visible_points} >= 1, mask_outline_px and "
                              "min_width_outlines >= 0")
        if len(self.weights) != 3 or min(self.weights) < 0:
            raise ConfigError(f"object map: eq. 22 needs three non-negative weights, got {self.weights}")


@dataclass
class MapObject:
    """One object: its cloud (one point per ``voxel`` cell, sorted by cell key) and what was seen of it."""

    id: int
    votes: np.ndarray  # (K,) score-weighted class votes
    keys: np.ndarray  # (M,) int64 sorted cell keys
    points: np.ndarray  # (M, 3) float32 world points
    colors: np.ndarray  # (M, 3) uint8
    cells: np.ndarray  # sorted overlap-cell keys of everything seen
    last_cells: np.ndarray  # sorted overlap-cell keys of the last keyframe's sighting
    coarse: np.ndarray  # sorted merge-cell keys of everything seen
    track_ids: set[int] = field(default_factory=set)
    keyframes: set[int] = field(default_factory=set)  # keyframes it was seen in
    sightings: int = 0
    first_frame: int = 0
    last_frame: int = 0
    _last_keyframe: int = -1
    _point_sum: np.ndarray = field(default_factory=lambda: np.zeros(3))
    lo: np.ndarray = field(default_factory=lambda: np.full(3, np.inf))  # axis-aligned bounds of the points
    hi: np.ndarray = field(default_factory=lambda: np.full(3, -np.inf))
    class_id: int = 0  # most voted class (kept with the votes)

    @property
    def confidence(self) -> float:
        """Share of the class votes its class holds."""
        total = float(self.votes.sum())
        return float(self.votes.max()) / total if total > 0 else 0.0

    @property
    def centroid(self) -> np.ndarray:
        """Mean of the object's points (eq. 16)."""
        return self._point_sum / max(len(self.points), 1)

    def __len__(self) -> int:
        return len(self.keys)


@dataclass(frozen=True)
class Sighting:
    """One detection's filtered cloud in one keyframe (world frame), before association."""

    detection: int  # index in the keyframe's detections; -1: kept from a frame before it (module step 8)
    class_id: int
    score: float
    track_id: int
    keys: np.ndarray
    points: np.ndarray
    colors: np.ndarray
    cells: np.ndarray
    centroid: np.ndarray
    points_cam: np.ndarray  # the same points in the camera frame (for pose constraints)
    lo: np.ndarray  # (3,) axis-aligned bounds of the points
    hi: np.ndarray
    coarse: np.ndarray  # sorted merge-cell keys


@dataclass(frozen=True)
class CameraClouds:
    """One keyframe's detections as filtered camera-frame points (what a keyframe keeps for later placement)."""

    points: np.ndarray  # (P, 3) float32 camera frame, outliers removed
    colors: np.ndarray  # (P, 3) uint8
    detection: np.ndarray  # (P,) int64 detection index of each point
    class_ids: np.ndarray  # (N,) int32
    scores: np.ndarray  # (N,) float32
    track_ids: np.ndarray  # (N,) int32, 0 = none

    @property
    def n(self) -> int:
        return len(self.class_ids)


#: a projected point is seen when the depth image holds it within this much (m) plus VISIBLE_REL of its depth
VISIBLE_ABS, VISIBLE_REL = 0.03, 0.02
#: points of an object projected per check at most (every k-th beyond)
MAX_PROJECTED = 4000


@dataclass(frozen=True)
class MaskView:
    """One keyframe's detection masks and depth image from its pose: where a map object's points fall in it."""

    ids: np.ndarray  # (H, W) detection index + 1 per pixel (0: no detection)
    depth: np.ndarray  # (H, W) metres, 0 = none
    intrinsics: CameraIntrinsics
    T_world_cam: np.ndarray  # (4, 4)
    n: int  # detections

    def masks_hit(self, points: np.ndarray, outline_px: int = 0) -> tuple[np.ndarray, int, float]:
        """Where the camera sees ``points`` (world) -- inside the image, in front, the depth image agreeing with
        their depth (not hidden, not a hole): per detection id how many fall on its mask or within ``outline_px``
        pixels of it (a point near two masks counts for both; id 0: points near no mask), how many it sees, and
        how wide they lie in the image (pixels, the smaller of the 5-95 % spans across and down)."""
        pts = np.asarray(points, np.float64)[::max(1, -(-len(points) // MAX_PROJECTED))]
        R, t = self.T_world_cam[:3, :3], self.T_world_cam[:3, 3]
        cam = (pts - t) @ R
        K = self.intrinsics
        z = cam[:, 2]
        front = z > 1e-3
        u = np.round(K.fx * cam[front, 0] / z[front] + K.cx).astype(np.int64)
        v = np.round(K.fy * cam[front, 1] / z[front] + K.cy).astype(np.int64)
        z = z[front]
        inside = (u >= 0) & (u < K.width) & (v >= 0) & (v < K.height)
        u, v, z = u[inside], v[inside], z[inside]
        d = self.depth[v, u]
        seen = (d > 0) & (np.abs(d - z) <= VISIBLE_ABS + VISIBLE_REL * z)
        u, v = u[seen], v[seen]
        r = int(outline_px)
        near = np.stack([self.ids[np.clip(v + dv, 0, K.height - 1), np.clip(u + du, 0, K.width - 1)]
                         for du, dv in ((0, 0), (-r, 0), (r, 0), (0, -r), (0, r))], axis=1)
        near.sort(axis=1)
        first = np.ones(near.shape, bool)
        first[:, 1:] = near[:, 1:] != near[:, :-1]  # each id once per point
        hits = np.bincount(near[first & (near > 0)], minlength=self.n + 1)
        hits[0] = int(np.sum(near[:, -1] == 0))  # sorted: the largest id of the five is 0, no mask near
        width = 0.0 if len(u) == 0 else float(min(np.subtract(*np.percentile(u, [95, 5])),
                                                  np.subtract(*np.percentile(v, [95, 5])))) + 1.0
        return hits, len(u), width


class ObjectMap:
    """Objects accumulated over keyframes (see the module docstring); ``integrate`` once per keyframe."""

    def __init__(self, label_set: LabelSet, params: ObjectMapParams | None = None) -> None:
        self.label_set = label_set
        self.params = ObjectMapParams() if params is None else params
        self.objects: dict[int, MapObject] = {}
        self.merged_into: dict[int, int] = {}
        self._next_id = 1
        self.keyframes = 0
        self.points_in = 0  # points back-projected from masks (before any filter)
        self.points_after_sor = 0
        self.merged_masks = 0  # sightings left out because they covered several objects
        self.parts_merged = 0  # objects seen apart merged as parts of one (step 6)
        self.track_frames: dict[int, int] = {}  # track id -> tracked frames it appeared in
        self._view: MaskView | None = None  # the keyframe being integrated, when its masks are known
        self._hits: dict[int, tuple[np.ndarray, int] | None] = {}
        #: track id -> its latest detection since the last keyframe: (class, score, camera points, colours, pose)
        self._window: dict[int, tuple[int, float, np.ndarray, np.ndarray, np.ndarray]] = {}
        self.window_sightings = 0  # sightings taken from frames between keyframes (step 8)

    # ------------------------------------------------------------------ queries
    def count_track_frames(self, track_ids: np.ndarray) -> None:
        """Note the track ids of one tracked frame (every frame, keyframe or not): the paper's rule counts how often
        an object's id appears, and the tracker sees it in many more frames than become keyframes."""
        for t in np.asarray(track_ids).tolist():
            if t > 0:
                self.track_frames[t] = self.track_frames.get(t, 0) + 1

    def frames_seen(self, obj: MapObject) -> int:
        """Tracked frames in which one of the object's track ids appeared (at least its keyframe sightings)."""
        return max(sum(self.track_frames.get(t, 0) for t in obj.track_ids), obj.sightings)

    def real_objects(self) -> list[MapObject]:
        """Objects whose id appeared at least ``min_sightings`` times (the paper's rule against false detections:
        in tracked frames, or in keyframes when tracks are not counted) and that were mapped from at least
        ``min_keyframes`` keyframes, by id."""
        p = self.params
        return [o for _, o in sorted(self.objects.items())
                if self.frames_seen(o) >= p.min_sightings and o.sightings >= p.min_keyframes]

    def objects_of_class(self, name: str) -> list[MapObject]:
        """Real objects whose class is ``name``."""
        cid = self.label_set.id_of(name)
        return [o for o in self.real_objects() if o.class_id == cid]

    def nearest(self, point: np.ndarray, class_name: str | None = None) -> tuple[MapObject | None, float]:
        """The real object (of ``class_name``, if given) whose cloud comes closest to ``point``, and the distance."""
        candidates = self.objects_of_class(class_name) if class_name else self.real_objects()
        best, best_d = None, np.inf
        p = np.asarray(point, np.float64).reshape(3)
        for o in candidates:
            d = float(np.sqrt(((o.points - p) ** 2).sum(axis=1).min()))
            if d < best_d:
                best, best_d = o, d
        return best, best_d

    def resolve(self, object_id: int) -> int:
        """The id an object id lives on under after merges."""
        while object_id in self.merged_into:
            object_id = self.merged_into[object_id]
        return object_id

    # ------------------------------------------------------------------ integration
    def integrate(self, instances: Instances, depth: np.ndarray, rgb: np.ndarray, intrinsics: CameraIntrinsics,
                  T_world_cam: np.ndarray, frame_index: int) -> np.ndarray:
        """Add one keyframe's tracked detections; returns the object id each joined (0: too few points)."""
        view = MaskView(np.asarray(instances.ids), np.asarray(depth), intrinsics,
                        np.asarray(T_world_cam, np.float64), len(instances)) if self.params.mask_check else None
        return self.integrate_clouds(self.extract(instances, depth, rgb, intrinsics), T_world_cam, frame_index,
                                     view=view)

    def note(self, instances: Instances, depth: np.ndarray, rgb: np.ndarray, intrinsics: CameraIntrinsics,
             T_world_cam: np.ndarray) -> None:
        """A tracked frame between keyframes: keep each tracked detection's cloud, the latest per track id, for
        the next keyframe to use where its detector misses the object (module step 8)."""
        tracks = instances.track_ids
        if not (self.params.window_sightings and self.params.mask_check) or tracks is None or not np.any(tracks > 0):
            return
        counted = self.points_in, self.points_after_sor
        clouds = self.extract(instances, depth, rgb, intrinsics)
        self.points_in, self.points_after_sor = counted  # only what keyframes integrate is counted
        T = np.asarray(T_world_cam, np.float64)
        order = np.argsort(clouds.detection, kind="stable")
        bounds = np.searchsorted(clouds.detection[order], np.arange(clouds.n + 1))
        for k in np.flatnonzero((clouds.track_ids > 0) & (np.diff(bounds) >= self.params.min_points)):
            rows = order[bounds[k]:bounds[k + 1]]
            self._window[int(clouds.track_ids[k])] = (int(clouds.class_ids[k]), float(clouds.scores[k]),
                                                      clouds.points[rows], clouds.colors[rows], T)

    def _missed_sightings(self, clouds: CameraClouds, view: MaskView | None) -> list[Sighting]:
        """The kept detections (:meth:`note`) of tracks this keyframe does not detect whose points the keyframe's
        camera sees mostly in no mask: objects in view its detector missed (module step 8); the buffer is emptied."""
        window, self._window = self._window, {}
        if view is None or not window:
            return []
        p = self.params
        detected = set(clouds.track_ids.tolist())
        out: list[Sighting] = []
        for track, (cls, score, pts, colors, T) in window.items():
            if track in detected:
                continue
            world = pts.astype(np.float64) @ T[:3, :3].T + T[:3, 3]
            hits, seen, _ = view.masks_hit(world, p.mask_outline_px)
            if seen < p.min_visible_points or hits[0] < p.mask_share * seen or \
                    self._shown_pixels(pts, world, view.T_world_cam, seen) < p.window_min_pixels:
                continue
            one = CameraClouds(pts, colors, np.zeros(len(pts), np.int64), np.array([cls], np.int32),
                               np.array([score], np.float32), np.array([track], np.int32))
            out += [replace(s, detection=-1) for s in self.place(one, T)]
        self.window_sightings += len(out)
        return out

    def _shown_pixels(self, pts_then: np.ndarray, world: np.ndarray, T_now: np.ndarray, seen: int) -> float:
        """Pixels a kept cloud (one point per ``pixel_stride``-squared mask pixels at its frame's depth) covers in
        a keyframe whose camera sees ``seen`` of its (up to ``MAX_PROJECTED``) projected points."""
        sampled = len(world[::max(1, -(-len(world) // MAX_PROJECTED))])
        z_then = float(np.mean(pts_then[:, 2]))
        z_now = float(np.mean((world - T_now[:3, 3]) @ T_now[:3, 2]))
        scale = (z_then / z_now) ** 2 if z_now > 1e-3 else 0.0
        return seen / max(sampled, 1) * len(world) * self.params.pixel_stride ** 2 * scale

    def integrate_clouds(self, clouds: CameraClouds, T_world_cam: np.ndarray, frame_index: int, *,
                         view: MaskView | None = None) -> np.ndarray:
        """Add one keyframe's filtered detection clouds seen from ``T_world_cam`` (see :meth:`integrate`); ``view``
        (its masks and depth) lets the image veto associations and merges (module step 7) and brings in what its
        detector missed (step 8)."""
        sightings = self.place(clouds, T_world_cam) + self._missed_sightings(clouds, view)
        self.keyframes += 1
        self._view, self._hits = view, {}
        assigned = np.zeros(clouds.n, np.int64)
        touched: list[int] = []
        matches = self._associate(sightings)
        for i, s in enumerate(sightings):
            obj = matches.get(i)
            if obj is None:
                obj = self._new_object(s, frame_index)
            else:
                self._add(obj, s, frame_index)
            if s.detection >= 0:
                assigned[s.detection] = obj.id
            touched.append(obj.id)
        self._index()
        self._hits = {}  # the touched objects now hold this keyframe's points
        for obj_id in dict.fromkeys(touched):
            self._merge_around(obj_id)
        self._view, self._hits = None, {}
        return np.array([self.resolve(int(i)) if i else 0 for i in assigned], np.int64)

    def extract(self, instances: Instances, depth: np.ndarray, rgb: np.ndarray,
                intrinsics: CameraIntrinsics) -> CameraClouds:
        """Each detection's points in the camera frame after back-projection and outlier removal (eq. 18)."""
        p = self.params
        s = p.pixel_stride
        d = np.asarray(depth[::s, ::s], np.float64)
        ids = np.where((d >= p.min_depth) & (d <= p.max_depth) & np.isfinite(d), instances.ids[::s, ::s], 0)
        ids = np.ascontiguousarray(ids, np.int32)
        rays = pixel_rays(intrinsics)
        x = rays.x[::s][None, :] * d
        y = rays.y[::s][:, None] * d
        # statistical outlier removal (eq. 18) with each point's grid neighbours in its mask as its K-neighbourhood
        mean_d = grid_neighbour_distances(ids, x, np.ascontiguousarray(y), d)
        v, u = np.nonzero(ids)
        det = ids[v, u].astype(np.int64) - 1
        counts = np.bincount(det, minlength=len(instances))
        self.points_in += len(det)
        keep = outlier_mask(mean_d[v, u], det, len(instances), p.sor_k) & (counts >= p.min_points)[det]
        v, u, det = v[keep], u[keep], det[keep]
        self.points_after_sor += len(det)
        tracks = instances.track_ids if instances.track_ids is not None else np.zeros(len(instances), np.int32)
        return CameraClouds(np.column_stack([x[v, u], y[v, u], d[v, u]]).astype(np.float32), rgb[v * s, u * s], det,
                            np.asarray(instances.class_ids, np.int32), np.asarray(instances.scores, np.float32),
                            np.asarray(tracks, np.int32))

    def place(self, clouds: CameraClouds, T_world_cam: np.ndarray) -> list[Sighting]:
        """Each detection's cloud in the world, voxel-filtered (per cell the point nearest its centre)."""
        p = self.params
        pts = clouds.points.astype(np.float64)
        det = clouds.detection
        world = pts @ T_world_cam[:3, :3].T + T_world_cam[:3, 3]
        scaled = world / p.voxel
        cell = np.floor(scaled).astype(np.int64)
        # one int64 sort key: detection (7 bits), cell relative to the keyframe's corner (16 bits per axis) and the
        # point's squared distance from the cell centre (8 bits), so per (detection, cell) the nearest comes first
        rel = cell - cell.min(axis=0) if len(cell) else cell
        if len(cell) and (rel.max() >= 1 << 16 or clouds.n >= 1 << 7):
            order = np.lexsort((((scaled - cell - 0.5) ** 2).sum(axis=1), pack_cells(cell), det))
            group = np.stack([det, pack_cells(cell)], 1)[order]
            first = np.ones(len(order), bool)
            first[1:] = np.any(group[1:] != group[:-1], axis=1)
        else:
            off = np.minimum(((scaled - cell - 0.5) ** 2).sum(axis=1) * (255 / 0.75), 255).astype(np.int64)
            key = (det << 56) | (rel[:, 0] << 40) | (rel[:, 1] << 24) | (rel[:, 2] << 8) | off
            order = np.argsort(key)
            group = key[order] >> 8
            first = np.ones(len(order), bool)
            first[1:] = group[1:] != group[:-1]
        rep = order[first]
        rep_det = det[rep]
        bounds = np.searchsorted(rep_det, np.arange(clouds.n + 1))
        rep_world = world[rep]
        cells, cell_bounds, cells_ok = cells_per_segment(rep_world, bounds, p.overlap_voxel, _KEY_BITS)
        coarse, coarse_bounds, coarse_ok = cells_per_segment(rep_world, bounds, p.merge_voxel, _KEY_BITS)
        if not (cells_ok and coarse_ok):
            raise ConfigError(_OUT_OF_RANGE)
        mean, lo, hi = segment_bounds_and_mean(rep_world, bounds)
        rep_keys, rep_points = pack_cells(cell[rep]), rep_world.astype(np.float32)
        rep_colors, rep_cam = clouds.colors[rep], pts[rep]
        out: list[Sighting] = []
        for k in range(clouds.n):
            a, b = bounds[k], bounds[k + 1]
            if b - a < p.min_points:
                continue
            out.append(Sighting(k, int(clouds.class_ids[k]), float(clouds.scores[k]), int(clouds.track_ids[k]),
                                rep_keys[a:b], rep_points[a:b], rep_colors[a:b],
                                cells[cell_bounds[k]:cell_bounds[k + 1]], mean[k], rep_cam[a:b], lo[k], hi[k],
                                coarse[coarse_bounds[k]:coarse_bounds[k + 1]]))
        return out

    # ------------------------------------------------------------------ association
    def score(self, same_track: bool, distance: float, overlap: float) -> float:
        """Eq. 22: ``P = w . (P_ID, D, M)`` with the distance and overlap terms scaled to the paper's thresholds."""
        p = self.params
        d_term = max(0.0, 1.0 - distance / p.centroid_distance)
        m_term = min(1.0, overlap / p.overlap_threshold)
        w = p.weights
        return w[0] * float(same_track) + w[1] * d_term + w[2] * m_term

    def _associate(self, sightings: list[Sighting]) -> dict[int, MapObject]:
        """Sighting index -> the existing object it belongs to by eq. 22: one-to-one per keyframe (two
        detections of one image are two objects), the assignment with the highest total score above ``K``."""
        pairs: dict[tuple[int, int], float] = {}
        self._index()
        for i, s in enumerate(sightings):
            candidates = self._candidates(s.lo, s.hi, s.class_id, s.track_id)
            if self._spans_several(s, candidates):
                self.merged_masks += 1
                continue
            for obj in candidates:
                if self._mask_says_apart(obj, s.detection + 1):
                    continue
                same = s.track_id > 0 and s.track_id in obj.track_ids
                dist = float(np.linalg.norm(obj.centroid - s.centroid))
                overlap = max(overlap_iou(s.cells, obj.last_cells), overlap_share(s.cells, obj.cells))
                score = self.score(same, dist, overlap)
                if score > self.params.score_threshold:
                    pairs[i, obj.id] = score
        if not pairs:
            return {}
        obj_ids = sorted({o for _, o in pairs})
        col = {o: j for j, o in enumerate(obj_ids)}
        gain = np.zeros((len(sightings), len(obj_ids)))
        for (i, o), score in pairs.items():
            gain[i, col[o]] = score
        rows, cols = linear_sum_assignment(-gain)
        return {int(r): self.objects[obj_ids[c]] for r, c in zip(rows, cols, strict=True) if gain[r, c] > 0}

    def _visible_hits(self, obj: MapObject) -> tuple[np.ndarray, int] | None:
        """:meth:`MaskView.masks_hit` of ``obj``'s points in the keyframe being integrated; None without a view or
        when the camera sees fewer than ``min_visible_points`` of them or sees them narrower than
        ``min_width_outlines`` outline errors (cached per keyframe and stage)."""
        if self._view is None or float(np.max(obj.hi - obj.lo)) > self.params.mask_check_max_size:
            return None
        if obj.id not in self._hits:
            p = self.params
            hits, seen, width = self._view.masks_hit(obj.points, p.mask_outline_px)
            judged = seen >= p.min_visible_points and width >= p.min_width_outlines * max(p.mask_outline_px, 1)
            self._hits[obj.id] = (hits, seen) if judged else None
        return self._hits[obj.id]

    def _mask_says_apart(self, obj: MapObject, detection_id: int) -> bool:
        """Whether the camera sees most of ``obj`` away from the mask ``detection_id`` (beyond its outline's
        error): that detection is not it."""
        found = self._visible_hits(obj)
        return found is not None and found[0][detection_id] < self.params.mask_share * found[1]

    def _seen_in(self, obj: MapObject) -> int | None:
        """The one mask (detection id) most of ``obj``'s visible points fall on or near; 0 when most fall near no
        mask; None when it is not seen, or not clearly in one place."""
        found = self._visible_hits(obj)
        if found is None:
            return None
        hits, seen = found
        places = np.flatnonzero(hits >= self.params.mask_share * seen)
        return int(places[0]) if len(places) == 1 else None

    def _masks_tell_apart(self, a: MapObject, b: MapObject) -> bool:
        """Whether the keyframe sees the two objects in different masks (one possibly in none): two things."""
        in_a, in_b = self._seen_in(a), self._seen_in(b)
        return in_a is not None and in_b is not None and in_a != in_b

    def _spans_several(self, s: Sighting, candidates: list[MapObject]) -> bool:
        """Whether the sighting covers most of two or more objects of its class: a mask that merged neighbours
        (books side by side) would otherwise glue them into one object."""
        covered = 0
        for obj in candidates:
            if obj.class_id == s.class_id and len(obj.last_cells) and \
                    overlap_share(obj.last_cells, s.cells) >= SPAN_SHARE:
                covered += 1
        return covered >= 2

    def _index(self) -> None:
        """Snapshot of every object's id, class and bounds (arrays) and which objects each track id saw."""
        objs = list(self.objects.values())
        self._ix_ids = np.array([o.id for o in objs], np.int64)
        self._ix_cls = np.array([o.class_id for o in objs], np.int64)
        self._ix_lo = np.array([o.lo for o in objs]).reshape(-1, 3)
        self._ix_hi = np.array([o.hi for o in objs]).reshape(-1, 3)
        self._ix_track: dict[int, list[int]] = {}
        for o in objs:
            for t in o.track_ids:
                self._ix_track.setdefault(t, []).append(o.id)

    def _candidates(self, lo: np.ndarray, hi: np.ndarray, class_id: int, track_id: int) -> list[MapObject]:
        """Objects of ``class_id`` whose bounds meet the box ``lo``-``hi`` (within an overlap cell), and those seen
        under ``track_id``. Without the track id a pair needs overlapping cells to pass eq. 22 (the distance term
        alone stays below ``K``), so objects apart are never compared."""
        m = self.params.overlap_voxel
        meets = np.all(self._ix_lo <= hi + m, axis=1) & np.all(self._ix_hi >= lo - m, axis=1)
        near = (self._ix_cls == class_id) & meets
        ids = set(self._ix_ids[near].tolist())
        if track_id > 0:
            ids.update(self._ix_track.get(track_id, ()))
        return [self.objects[i] for i in sorted(ids) if i in self.objects]

    def _new_object(self, s: Sighting, frame_index: int) -> MapObject:
        votes = np.zeros(len(self.label_set))
        obj = MapObject(self._next_id, votes, s.keys[:0], s.points[:0], s.colors[:0], s.cells[:0], s.cells[:0],
                        s.cells[:0], first_frame=frame_index)
        self._next_id += 1
        self.objects[obj.id] = obj
        self._add(obj, s, frame_index)
        return obj

    def _add(self, obj: MapObject, s: Sighting, frame_index: int) -> None:
        obj.votes[min(s.class_id, len(obj.votes) - 1)] += s.score
        obj.class_id = int(np.argmax(obj.votes))
        obj.lo, obj.hi = np.minimum(obj.lo, s.lo), np.maximum(obj.hi, s.hi)
        if s.track_id > 0:
            obj.track_ids.add(s.track_id)
        obj.keyframes.add(self.keyframes)
        if obj._last_keyframe != self.keyframes:  # two pieces of one object in a keyframe: one sighting
            obj.sightings += 1
            obj.last_cells = s.cells
        else:
            obj.last_cells = sorted_union(obj.last_cells, s.cells)
        obj._last_keyframe = self.keyframes
        obj.last_frame = frame_index
        # cells the object already has keep their point; both key lists are sorted: one merge pass
        obj.keys, obj.points, obj.colors, added = merge_cells(obj.keys, obj.points, obj.colors, s.keys, s.points,
                                                              s.colors)
        obj._point_sum = obj._point_sum + added
        obj.cells = sorted_union(obj.cells, s.cells)
        obj.coarse = sorted_union(obj.coarse, s.coarse)

    # ------------------------------------------------------------------ merging
    def _merge_around(self, obj_id: int) -> None:
        """Merge ``obj_id`` with any neighbour of its class that eq. 22 says is the same object."""
        obj_id = self.resolve(obj_id)
        obj = self.objects.get(obj_id)
        if obj is None:
            return
        for other in self._candidates(obj.lo, obj.hi, obj.class_id, -1):
            if other.id == obj.id or other.class_id != obj.class_id or other.id not in self.objects:
                continue
            if self._part_of(obj, other):  # one lies on the other's surface: one object seen in parts
                keep, gone = (obj, other) if obj.id < other.id else (other, obj)
                self._absorb(keep, gone)
                self.parts_merged += 1
                obj = keep
                continue
            if len(obj.keyframes & other.keyframes) >= MIN_SEEN_APART:
                continue  # the segmenter told them apart in the same images: two objects side by side
            if self._masks_tell_apart(obj, other):
                continue
            same = bool(obj.track_ids & other.track_ids)
            dist = float(np.linalg.norm(obj.centroid - other.centroid))
            overlap = overlap_containment(obj.cells, other.cells)
            if min(len(obj.coarse), len(other.coarse)) >= MIN_COARSE_CELLS:  # large objects only: not two books
                overlap = max(overlap, overlap_containment(obj.coarse, other.coarse))
            if self.score(same, dist, overlap) > self.params.score_threshold:
                keep, gone = (obj, other) if obj.id < other.id else (other, obj)
                self._absorb(keep, gone)
                obj = keep

    def _part_of(self, a: MapObject, b: MapObject) -> bool:
        """Whether two large objects (``MIN_COARSE_CELLS`` merge cells each) are one seen in parts: where their
        bounds overlap, the one with fewer cells there has at least ``PART_REGION_SHARE`` of its cells there and
        ``part_share`` of those lie within ``NEAR_CELLS`` of the other's (on its surface, or on the far face of a
        thin part of it), even when a segmenter told them apart in some images."""
        p = self.params
        if p.part_share > 1.0 or min(len(a.coarse), len(b.coarse)) < MIN_COARSE_CELLS:
            return False
        lo, hi = np.maximum(a.lo, b.lo), np.minimum(a.hi, b.hi)
        if np.any(lo > hi):
            return False
        cell_lo, cell_hi = np.floor(lo / p.overlap_voxel), np.floor(hi / p.overlap_voxel)
        in_a, in_b = cells_within(a.cells, cell_lo, cell_hi), cells_within(b.cells, cell_lo, cell_hi)
        part, whole, inside = (a, b, in_a) if in_a.sum() <= in_b.sum() else (b, a, in_b)
        if inside.sum() < PART_REGION_SHARE * len(part.cells):
            return False
        return overlap_near(part.cells[inside], whole.cells) >= p.part_share

    def _absorb(self, keep: MapObject, gone: MapObject) -> None:
        keep.votes += gone.votes
        keep.class_id = int(np.argmax(keep.votes))
        keep.lo, keep.hi = np.minimum(keep.lo, gone.lo), np.maximum(keep.hi, gone.hi)
        keep.track_ids |= gone.track_ids
        keep.keyframes |= gone.keyframes
        keep.sightings = keep.sightings + gone.sightings
        keep.first_frame = min(keep.first_frame, gone.first_frame)
        keep.last_frame = max(keep.last_frame, gone.last_frame)
        keep.last_cells = sorted_union(keep.last_cells, gone.last_cells) if gone._last_keyframe == self.keyframes \
            else keep.last_cells
        keep.keys, keep.points, keep.colors, added = merge_cells(keep.keys, keep.points, keep.colors, gone.keys,
                                                                 gone.points, gone.colors)
        keep._point_sum = keep._point_sum + added
        keep.cells = sorted_union(keep.cells, gone.cells)
        keep.coarse = sorted_union(keep.coarse, gone.coarse)
        del self.objects[gone.id]
        self.merged_into[gone.id] = keep.id
        self._hits.pop(keep.id, None)  # it holds more points now


def outlier_mask(mean_distance: np.ndarray, groups: np.ndarray, n_groups: int, k: float) -> np.ndarray:
    """(N,) bool: points kept by statistical outlier removal (eq. 18): a point goes when its mean neighbour
    distance exceeds ``t = m + k s``, the mean and standard deviation of those distances over its group (points
    without a neighbour, ``inf``, always go and are left out of the statistics)."""
    finite = np.isfinite(mean_distance)
    g = groups[finite]
    dist = mean_distance[finite]
    cnt = np.bincount(g, minlength=n_groups)
    m = np.bincount(g, weights=dist, minlength=n_groups) / np.maximum(cnt, 1)
    var = np.bincount(g, weights=(dist - m[g]) ** 2, minlength=n_groups) / np.maximum(cnt, 1)
    t = m + k * np.sqrt(var)
    return finite & (np.where(finite, mean_distance, 0.0) <= t[groups])


def pack_cells(cells: np.ndarray) -> np.ndarray:
    """(N,) int64 keys of (N, 3) integer cell coordinates (21 bits each, offset to stay non-negative)."""
    c = np.asarray(cells, np.int64) + _KEY_OFFSET
    if c.size and (c.min() < 0 or c.max() >= 1 << _KEY_BITS):
        raise ConfigError(_OUT_OF_RANGE)
    return (c[:, 0] << (2 * _KEY_BITS)) | (c[:, 1] << _KEY_BITS) | c[:, 2]


def overlap_iou(a: np.ndarray, b: np.ndarray) -> float:
    """Eq. 21, ``M = AB / (A + B - AB)``, of two sorted unique cell-key arrays."""
    if len(a) == 0 or len(b) == 0:
        return 0.0
    ab = sorted_intersection_size(a, b)
    return ab / (len(a) + len(b) - ab)


def overlap_share(a: np.ndarray, b: np.ndarray) -> float:
    """``AB / A``: the share of cell set ``a`` that ``b`` also holds."""
    if len(a) == 0:
        return 0.0
    return sorted_intersection_size(a, b) / len(a)


#: cells within this many cells of another (centre to centre) are near it: 2 overlap cells, 6 cm, the thickness
#: of a chair's back or a table top, whose faces seen from its two sides lie that far apart
NEAR_CELLS = 2
#: the offsets of the cells near a cell (itself included) as differences of packed cell keys
_NEAR_KEYS = np.array([(dx << (2 * _KEY_BITS)) + (dy << _KEY_BITS) + dz
                       for dx in range(-NEAR_CELLS, NEAR_CELLS + 1) for dy in range(-NEAR_CELLS, NEAR_CELLS + 1)
                       for dz in range(-NEAR_CELLS, NEAR_CELLS + 1) if dx * dx + dy * dy + dz * dz <= NEAR_CELLS ** 2],
                      np.int64)


def cells_within(keys: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """(N,) bool: which packed cell keys have cell coordinates within ``lo``-``hi`` (3,), both included."""
    mask = (1 << _KEY_BITS) - 1
    xyz = np.column_stack([keys >> (2 * _KEY_BITS), (keys >> _KEY_BITS) & mask, keys & mask]) - _KEY_OFFSET
    return np.all((xyz >= lo) & (xyz <= hi), axis=1)


def overlap_near(a: np.ndarray, b: np.ndarray) -> float:
    """The share of sorted cell keys ``a`` within ``NEAR_CELLS`` cells of one of sorted cell keys ``b``: a part's
    surface seen from its other side lies a few centimetres from the whole's."""
    if len(a) == 0 or len(b) == 0:
        return 0.0
    near = np.zeros(len(a), bool)
    for off in _NEAR_KEYS:
        shifted = a + off
        at = np.minimum(np.searchsorted(b, shifted), len(b) - 1)
        near |= b[at] == shifted
    return float(near.mean())


def overlap_containment(a: np.ndarray, b: np.ndarray) -> float:
    """``AB / min(A, B)``: the share of the smaller cell set the larger one also holds."""
    if len(a) == 0 or len(b) == 0:
        return 0.0
    return sorted_intersection_size(a, b) / min(len(a), len(b))


@dataclass(frozen=True)
class OrientedBox:
    """A box upright along ``up``: centre (3,), rotation (3, 3) whose columns are its axes (the third = up), and
    full edge lengths (3,) along them (metres)."""

    center: np.ndarray
    rotation: np.ndarray
    extent: np.ndarray


def upright_box(points: np.ndarray, up: np.ndarray) -> OrientedBox:
    """The box standing upright on ``up`` with the smallest footprint around ``points``: furniture stands
    upright, so only its heading is free, and the heading comes from the minimum-area rectangle of the points'
    horizontal positions (``cv2.minAreaRect``, rotating calipers on their convex hull)."""
    import cv2

    pts = np.asarray(points, np.float64).reshape(-1, 3)
    up = np.asarray(up, np.float64) / np.linalg.norm(up)
    ref = np.array([1.0, 0.0, 0.0]) if abs(up[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = ref - up * (ref @ up)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(up, e1)
    if len(pts) >= 3:
        h = np.column_stack([pts @ e1, pts @ e2])
        origin = h.mean(axis=0)
        (_, _), (_, _), angle = cv2.minAreaRect((h - origin).astype(np.float32))
        a = np.radians(angle)
        e1, e2 = np.cos(a) * e1 + np.sin(a) * e2, -np.sin(a) * e1 + np.cos(a) * e2
    R = np.column_stack([e1, e2, up])
    if np.linalg.det(R) < 0:
        R[:, 1] = -R[:, 1]
    local = pts @ R
    lo, hi = local.min(axis=0), local.max(axis=0)
    return OrientedBox(R @ ((lo + hi) / 2), R, hi - lo)
