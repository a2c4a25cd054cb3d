"""Dense RGB-D SLAM: dense odometry for every frame, ORB features on keyframes for loop closure and
relocalisation, and a keyframe pose graph (gtsam) that a closed loop re-optimises.

Each frame is aligned densely (photometric + geometric, :class:`~semmap.poses.odometry.DenseOdometry`) to the
current keyframe, and that is what every frame's pose rests on: on the simulated sequences it is 3-9x more
accurate than the feature SLAM ``slam-orb`` (ATE 0.01-0.05 cm against 0.09-0.17 cm), on 7-Scenes as accurate
(2.52 against 2.79 cm; ``benchmarks/bench_tracking.py``, docs/BENCHMARKS.md). Keyframes also get
ORB features with depth. A new keyframe is compared with older ones by descriptor retrieval; a candidate is
verified by PnP + RANSAC on its keypoints' 3D points and refined by dense alignment of the two keyframes, and
the pose graph is optimised: consecutive keyframes are tied by their odometry, each keyframe also by a dense
alignment to the keyframe before its predecessor (so no single step carries the chain alone), plus every loop.
A frame the dense alignment rejects is relocalised against recent and similar keyframes by the same PnP check
before the motion model is trusted. Every frame's final pose is its keyframe's optimised pose times its pose
relative to that keyframe, blended towards the next keyframe's correction for frames between the two.
"""

from __future__ import annotations

import logging
import zlib
from collections import OrderedDict
from dataclasses import dataclass, field

import numpy as np

from semmap.errors import ConfigError
from semmap.poses.dense_align import DenseImage, grey
from semmap.poses.odometry import DenseOdometry, FrameReport, OdometryConfig, Reference
from semmap.poses.slam.config import SlamConfig
from semmap.poses.slam.features import VIRTUAL_BASELINE, FrameFeatures, OrbExtractor
from semmap.poses.slam.matching import match_brute_force, nearest_owner_votes
from semmap.poses.slam.optimisation import optimise_pose_graph
from semmap.poses.slam.pose_solver import PinholeModel, pnp_ransac
from semmap.types import CameraIntrinsics, Frame, Trajectory, interpolate_pose, invert_pose, pose_change

log = logging.getLogger("semmap")

#: the dense refinement of a PnP pose may move it at most this far (metres, degrees)
POLISH_M = 0.1
POLISH_DEG = 5.0
#: keyframe image pyramids kept in memory (about 8 MB each at 640x480; older ones are rebuilt when needed from
#: the grey image and depth every keyframe keeps compressed, 0.3-0.4 MB instead of 1.5 MB at 640x480)
PYRAMID_CACHE = 8


@dataclass(frozen=True)
class DenseSlamConfig:
    """Settings of :class:`DenseSlam`; the defaults are the variant that measured best (see the benchmark)."""

    odometry: OdometryConfig = field(default_factory=OdometryConfig)  #: per-frame dense alignment and keyframes
    features: SlamConfig = field(default_factory=SlamConfig)  #: ORB extraction (n_features, levels, depth range)
    loop_closure: bool = True  #: look for revisits at every keyframe and re-optimise the pose graph
    loop_min_gap: int = 8  #: a loop candidate is at least this many keyframes older
    loop_candidates: int = 3  #: most similar older keyframes verified geometrically
    loop_cooldown: int = 2  #: keyframes after a closed loop before the next search
    retrieval_features: int = 300  #: strongest descriptors per keyframe used to rank loop candidates
    min_inliers: int = 40  #: PnP inliers that confirm a loop or a relocalisation
    min_fitness: float = 0.4  #: share of pixels in correspondence after the dense refinement of a loop
    #: a loop must agree with the current estimate within this (metres, degrees): drift is far smaller, and a
    #: repeated texture matching the wrong place is rejected
    loop_max_correction: float = 0.5
    loop_max_correction_deg: float = 30.0
    #: a loop's dense alignment, run both ways, must agree within this (metres, degrees): a pair that far apart
    #: can converge to a wrong pose (on the simulated desk one such loop was 1.7 cm off and cost 5x the ATE)
    loop_consistency: float = 0.005
    loop_consistency_deg: float = 0.3
    #: a new keyframe is also aligned densely to this many keyframes before its predecessor (from the odometry's
    #: estimate) and each alignment becomes a pose-graph edge, so no single keyframe-to-keyframe step carries the
    #: chain alone (0: odometry chain plus loops). 1 lowered the 7-Scenes ATE from 3.45 to 3.06 cm and the
    #: simulated loop's from 0.10 to 0.08 cm; 2 to 4 measured no better, for one more alignment per keyframe each
    covisible_edges: int = 1
    #: standard deviations of a pose-graph edge (radians, metres), odometry and loops alike
    edge_sigma: tuple[float, float] = (0.005, 0.01)

    def __post_init__(self) -> None:
        if not isinstance(self.odometry, OdometryConfig) or not isinstance(self.features, SlamConfig):
            raise ConfigError("DenseSlamConfig needs an OdometryConfig and a SlamConfig")
        if int(self.covisible_edges) < 0:
            raise ConfigError(f"DenseSlamConfig.covisible_edges must be 0 or more, got {self.covisible_edges!r}")
        for name in ("loop_min_gap", "loop_candidates", "retrieval_features", "min_inliers"):
            if int(getattr(self, name)) < 1:
                raise ConfigError(f"DenseSlamConfig.{name} must be at least 1, got {getattr(self, name)!r}")
        if self.min_inliers < 6:
            raise ConfigError(f"DenseSlamConfig.min_inliers must be at least 6 (PnP needs them), "
                              f"got {self.min_inliers}")
        if not 0.0 <= self.min_fitness <= 1.0:
            raise ConfigError(f"DenseSlamConfig.min_fitness must lie in [0, 1], got {self.min_fitness}")
        bounds = (*self.edge_sigma, self.loop_max_correction, self.loop_max_correction_deg, self.loop_consistency,
                  self.loop_consistency_deg)
        if min(bounds) <= 0:
            raise ConfigError("DenseSlamConfig: edge sigmas and loop bounds must be positive")


@dataclass(frozen=True)
class PackedImage:
    """An array compressed losslessly (zlib): keyframes keep their grey image and depth this way, because they
    are only read again to rebuild pyramids a loop needs (7-Scenes: 1.5 MB -> 0.3 MB per keyframe, 9 ms to pack)."""

    data: bytes
    shape: tuple[int, ...]
    dtype: str

    @classmethod
    def pack(cls, array: np.ndarray) -> PackedImage:
        array = np.ascontiguousarray(array)
        return cls(zlib.compress(array.tobytes(), 1), array.shape, array.dtype.str)

    def unpack(self) -> np.ndarray:
        return np.frombuffer(zlib.decompress(self.data), dtype=self.dtype).reshape(self.shape)

    @property
    def nbytes(self) -> int:
        return len(self.data)


@dataclass
class _Keyframe:
    """A keyframe: the frame it is, its ORB features, its grey image and depth (for dense alignments to it), and its
    pose in the odometry's own frame (``raw``) and after pose-graph optimisation (``T_wc``)."""

    frame: int
    parent: int  # the keyframe its odometry edge ties it to (-1 for the first)
    raw: np.ndarray
    T_wc: np.ndarray
    feats: FrameFeatures
    retrieval: np.ndarray
    grey: PackedImage
    depth: PackedImage


@dataclass
class DenseSlamStats:
    """Counters of a run (for reports and benchmarks)."""

    keyframes: int = 0
    loops: int = 0
    relocalisations: int = 0
    loop_frames: list[int] = field(default_factory=list)


class DenseSlam(DenseOdometry):
    """Dense odometry + keyframe pose graph with ORB loop closure and relocalisation (see the module docstring)."""

    name = "slam"

    def __init__(self, config: DenseSlamConfig | None = None) -> None:
        config = DenseSlamConfig() if config is None else config
        if not isinstance(config, DenseSlamConfig):
            raise ConfigError(f"DenseSlam needs a DenseSlamConfig, got {type(config).__name__}")
        super().__init__(config.odometry)
        self.slam_config = config
        self.stats = DenseSlamStats()
        self.keyframes: list[_Keyframe] = []
        self._kf_of_frame: list[int] = []  # keyframe each recorded frame was aligned to (or is)
        self._edges: list[tuple[int, int, np.ndarray, float]] = []  # pose-graph edges (i, j, T_i_j, weight)
        self._unoptimised = False  # edges were added since the last optimisation
        self._last_loop = -(10**9)
        self._extractor: OrbExtractor | None = None
        self._cam: PinholeModel | None = None
        self._anchor: tuple[int, np.ndarray] | None = None  # (keyframe, T_kf_frame) of a relocalised frame
        self._cached: tuple[Frame, FrameFeatures] | None = None  # the last frame's features (reused as keyframe)
        self._pyramids: OrderedDict[int, DenseImage] = OrderedDict()  # keyframe -> its pyramids (the newest used)

    # ------------------------------------------------------------------ hooks of DenseOdometry
    def _set_reference(self, frame: Frame, image: DenseImage, pose: np.ndarray) -> None:
        super()._set_reference(frame, image, pose)
        self._add_keyframe(frame, image, pose)

    def _record(self, frame: Frame, name: str, pose: np.ndarray, report: FrameReport) -> None:
        super()._record(frame, name, pose, report)
        self._kf_of_frame.append(len(self.keyframes) - 1)

    def _recover(self, frame: Frame, image: DenseImage, predicted: np.ndarray) -> np.ndarray | None:
        """Relocalise a frame the dense alignment rejected: PnP against the last keyframes and the most similar
        ones, refined densely; its pose in the odometry's frame, or None."""
        feats = self._features(frame)
        recent = list(range(max(0, len(self.keyframes) - 3), len(self.keyframes)))[::-1]
        similar = self._rank(feats, np.arange(len(self.keyframes)))
        for k in dict.fromkeys(recent + similar):
            found = self._register(feats, image, k)
            if found is not None:
                self.stats.relocalisations += 1
                log.debug("slam: frame %s relocalised against keyframe %d", frame.name or frame.index, k)
                self._anchor = (k, found)  # the frame becomes a keyframe tied to keyframe k by this pose
                return self.keyframes[k].raw @ found  # in the odometry's frame, through keyframe k
        return None

    # ------------------------------------------------------------------ keyframes and loops
    def _setup(self, intr: CameraIntrinsics) -> None:
        cfg = self.slam_config
        self._extractor = OrbExtractor(cfg.features, intr)
        self._cam = PinholeModel(intr.fx, intr.fy, intr.cx, intr.cy, VIRTUAL_BASELINE * intr.fx)

    def _features(self, frame: Frame) -> FrameFeatures:
        """ORB features of a frame (computed once: a relocalised frame becomes a keyframe right after)."""
        if self._cached is not None and self._cached[0] is frame:
            return self._cached[1]
        if self._extractor is None:
            self._setup(frame.intrinsics)
        depth = np.nan_to_num(frame.depth, nan=0.0, posinf=0.0, neginf=0.0)
        feats = self._extractor.extract(frame.rgb, depth)
        self._cached = (frame, feats)
        return feats

    def _add_keyframe(self, frame: Frame, image: DenseImage, raw: np.ndarray) -> None:
        cfg = self.slam_config
        feats = self._features(frame)
        if self.keyframes:
            # tied to the previous keyframe by the odometry, or to the keyframe it was relocalised against
            ref, rel = self._anchor or (len(self.keyframes) - 1, invert_pose(self.keyframes[-1].raw) @ raw)
            T_wc = self.keyframes[ref].T_wc @ rel
            self._edges.append((ref, len(self.keyframes), rel, 1.0))
        else:
            ref, T_wc = -1, raw.copy()
        self._anchor = None
        kf = _Keyframe(len(self._poses), ref, raw.copy(), T_wc, feats,
                       feats.desc[feats.strongest(cfg.retrieval_features)], PackedImage.pack(grey(frame.rgb)),
                       PackedImage.pack(frame.depth))
        self.keyframes.append(kf)
        self.stats.keyframes += 1
        k = len(self.keyframes) - 1
        self._remember(k, image)  # the odometry's reference from now on: its pyramids are needed right away
        self._link_covisible(k)
        if cfg.loop_closure:
            self._close_loop(k)

    def _link_covisible(self, k: int) -> None:
        """Align keyframe ``k`` densely to up to ``covisible_edges`` keyframes before its predecessor, starting
        from the odometry's estimate, and add each alignment that passes as a pose-graph edge (optimised with the
        next loop, or when the trajectory is asked for)."""
        kf = self.keyframes[k]
        for j in range(k - 2, max(-1, k - 2 - self.slam_config.covisible_edges), -1):
            T_j_k = self._refine(self._pyramid(k), self._pyramid(j), invert_pose(self.keyframes[j].raw) @ kf.raw)
            if T_j_k is not None:
                self._edges.append((j, k, T_j_k, 1.0))
                self._unoptimised = True

    def _rank(self, feats: FrameFeatures, candidates: np.ndarray) -> list[int]:
        """The ``loop_candidates`` keyframes among ``candidates`` most of whose descriptors are the nearest
        neighbours of ``feats``' strongest ones (one search over all keyframes' retrieval descriptors)."""
        cfg = self.slam_config
        if len(candidates) == 0 or len(feats) == 0:
            return []
        last = int(np.max(candidates)) + 1
        sizes = np.array([len(kf.retrieval) for kf in self.keyframes[:last]])
        database = np.concatenate([kf.retrieval for kf in self.keyframes[:last]])
        owner = np.repeat(np.arange(last), sizes)
        votes = nearest_owner_votes(feats.desc[feats.strongest(cfg.retrieval_features)], database, owner, last)
        scores = votes[np.asarray(candidates, np.int64)]
        order = np.argsort(-scores, kind="stable")[: cfg.loop_candidates]
        return [int(candidates[i]) for i in order if scores[i] >= cfg.min_inliers // 2]

    def _register(self, feats: FrameFeatures, image: DenseImage, k: int) -> np.ndarray | None:
        """``T_kf_frame`` of a frame relative to keyframe ``k``: ORB matches, PnP + RANSAC on the keyframe's 3D
        keypoints, then dense alignment of the two images from there; None when either check fails."""
        cfg = self.slam_config
        kf = self.keyframes[k]
        with_depth = np.flatnonzero(kf.feats.has_depth)
        if len(with_depth) < cfg.min_inliers or len(feats) < cfg.min_inliers:
            return None
        q, t = match_brute_force(feats.desc, kf.feats.desc[with_depth], max_dist=cfg.features.max_descriptor_distance,
                                 ratio=0.85)
        if len(q) < cfg.min_inliers:
            return None
        found = pnp_ransac(kf.feats.xyz[with_depth[t]], feats.uv[q], self._cam, None,
                           cfg.features.ransac_reprojection_error, max(cfg.features.ransac_iterations, 300), seed=k)
        if found is None or int(found[1].sum()) < cfg.min_inliers:
            return None
        kf_image = self._pyramid(k)
        T_kf_frame = self._refine(image, kf_image, invert_pose(found[0]))
        if T_kf_frame is None:
            return None
        # the alignment the other way round must land on the same pose, else one of them did not converge
        back = self._refine(kf_image, image, invert_pose(T_kf_frame))
        if back is None:
            return None
        dist, angle = pose_change(T_kf_frame, invert_pose(back))
        return T_kf_frame if dist <= cfg.loop_consistency and angle <= cfg.loop_consistency_deg else None

    def _pyramid(self, k: int) -> DenseImage:
        """Keyframe ``k``'s image pyramids (kept for the last few keyframes used, else rebuilt)."""
        if k in self._pyramids:
            self._pyramids.move_to_end(k)
            return self._pyramids[k]
        kf = self.keyframes[k]
        return self._remember(k, self._aligner.image(kf.grey.unpack(), kf.depth.unpack()))

    def _remember(self, k: int, image: DenseImage) -> DenseImage:
        self._pyramids[k] = image
        while len(self._pyramids) > PYRAMID_CACHE:
            self._pyramids.popitem(last=False)
        return image

    def _refine(self, source: DenseImage, target: DenseImage, T_init: np.ndarray) -> np.ndarray | None:
        """``T_target_source`` by dense alignment of two images from ``T_init`` (a PnP pose, which it should only
        polish), None when rejected or below ``min_fitness``."""
        T, fitness, _, reason = self._align(source, Reference(target, np.eye(4)), T_init)
        if reason or fitness < self.slam_config.min_fitness:
            return None
        dist, angle = pose_change(T_init, T)
        return T if dist <= POLISH_M and angle <= POLISH_DEG else None

    def _close_loop(self, k: int) -> None:
        """Look for an older keyframe that keyframe ``k`` revisits; on success re-optimise the pose graph."""
        cfg = self.slam_config
        if k - self._last_loop < cfg.loop_cooldown or k < cfg.loop_min_gap:
            return
        kf = self.keyframes[k]
        for j in self._rank(kf.feats, np.arange(k - cfg.loop_min_gap + 1)):
            T_j_k = self._register(kf.feats, self._pyramid(k), j)
            if T_j_k is None:
                continue
            dist, angle = pose_change(invert_pose(self.keyframes[j].T_wc) @ kf.T_wc, T_j_k)
            if dist > cfg.loop_max_correction or angle > cfg.loop_max_correction_deg:
                log.debug("slam: loop %d -> %d rejected (%.2f m, %.1f deg from the estimate)", k, j, dist, angle)
                continue
            self._edges.append((j, k, T_j_k, 1.0))
            self._optimise()
            self._last_loop = k
            self.stats.loops += 1
            self.stats.loop_frames.append(kf.frame)
            log.debug("slam: loop closed between keyframes %d and %d (%.3f m, %.2f deg)", k, j, dist, angle)
            return

    def _optimise(self) -> None:
        rot, trans = self.slam_config.edge_sigma
        poses = np.array([kf.T_wc for kf in self.keyframes])
        try:
            new = optimise_pose_graph(poses, self._edges, fixed=0, sigmas=(rot, trans))
        except RuntimeError:  # an indeterminate graph: keep the poses
            return
        for kf, T in zip(self.keyframes, new, strict=True):
            kf.T_wc = T
        self._unoptimised = False

    # ------------------------------------------------------------------ output
    def live_pose(self) -> np.ndarray | None:
        """The last frame's pose through its keyframe's pose as optimised so far (what ``trajectory`` will give it
        before blending towards the next keyframe, which does not exist yet): the online run's estimate."""
        if not self._poses:
            return None
        kf = self.keyframes[self._kf_of_frame[-1]]
        return kf.T_wc @ invert_pose(kf.raw) @ np.asarray(self._poses[-1])

    @property
    def loop_closures(self) -> int:
        return self.stats.loops

    def trajectory(self) -> Trajectory:
        """Every frame's pose: its keyframe's optimised pose times its odometry pose relative to that keyframe.

        A frame between keyframes k and k+1 (aligned to k, like k+1 itself) carries part of the error the graph
        found in the odometry step from k to k+1: it is blended from its pose through k towards its pose through
        k+1 by how far along it lies (frame count), so the trajectory does not jump at keyframe k+1.
        """
        if self._unoptimised:
            self._optimise()
        if not self._poses:
            return Trajectory(np.zeros(0), np.zeros((0, 4, 4)), ())
        raw = np.asarray(self._poses)
        ref = np.asarray(self._kf_of_frame)
        kf_raw = np.array([kf.raw for kf in self.keyframes])
        kf_opt = np.array([kf.T_wc for kf in self.keyframes])
        correction = kf_opt @ invert_pose(kf_raw)
        poses = correction[ref] @ raw
        start = np.array([kf.frame for kf in self.keyframes])
        for i in np.flatnonzero(ref + 1 < len(self.keyframes)):
            k = ref[i]
            after = self.keyframes[k + 1]
            if after.parent == k and start[k] < i < after.frame:
                alpha = (i - start[k]) / (after.frame - start[k])
                poses[i] = interpolate_pose(poses[i], correction[k + 1] @ raw[i], alpha)
        return Trajectory(np.asarray(self._stamps), poses, tuple(self._names))
