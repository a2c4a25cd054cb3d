"""Where a new recording lies in a prior map: its first frames localized by the particle filter (global, 6-DoF),
then the estimate refined by point-to-plane ICP of those frames' depth points against the map's occupied voxels.

``semmap run SEQ --continue PRIOR`` calls :func:`align_recording` with each frame's pose in the recording's own
frame (ground truth, a trajectory file or a tracker's); the result is the rigid transform ``T_prior_seq`` that
carries those poses into the prior's frame, and how the alignment went (for the run's report).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.spatial import cKDTree

from semmap.errors import ConfigError
from semmap.geometry import backproject
from semmap.localization._kernels import compile_kernels
from semmap.localization.filter import FilterSettings, ParticleFilter, PoseEstimate
from semmap.localization.motion import MotionMode
from semmap.localization.observation import DEFAULT_POINTS, ObservationKind, make_scan
from semmap.localization.prior import PriorMap
from semmap.types import Frame, TopKProbs, invert_pose, make_pose, pose_change, rotation_angle, transform_points

#: Particles of the global 6-DoF initialisation (the localization benchmark's global runs use as many).
ALIGN_PARTICLES = 10_000
#: At most this many frames are localized before the alignment gives up.
ALIGN_MAX_FRAMES = 60
#: Once converged, the filter runs this many more frames before its estimate is taken.
SETTLE_FRAMES = 3
#: ICP uses the depth points of at most this many of the last localized frames.
ICP_FRAMES = 8
#: ICP: correspondences farther than this many voxels are rejected (coarse to fine), iterations per stage.
ICP_STAGES_VOXELS = (4.0, 2.0, 1.0, 0.5)
ICP_ITERATIONS = 10
#: ICP points (source, after a voxel filter at half the map's resolution) at most.
ICP_MAX_POINTS = 20_000
#: The surface is thinned to one point per cell of this size (m) before its normals are estimated.
SURFACE_CELL_M = 0.015
#: An ICP correction larger than this is not trusted (the filter's estimate is kept).
ICP_MAX_CORRECTION_M, ICP_MAX_CORRECTION_DEG = 0.5, 10.0
#: The likelihood's endpoint σ is at least this many voxels of the prior map.
SIGMA_VOXELS = 0.75
#: Neighbours over which a voxel's surface normal is estimated.
NORMAL_NEIGHBOURS = 12

SegmentFn = Callable[[Frame], TopKProbs | None]


@dataclass
class Alignment:
    """The recording's frame in the prior's (``T_prior_seq``) and how it was found."""

    T_prior_seq: np.ndarray
    frames_localized: int
    converged_after: int  # frames until the filter reported convergence
    filter_estimate: PoseEstimate  # the filter's belief on the last localized frame
    T_filter: np.ndarray  # the transform the filter alone gives
    icp: dict = field(default_factory=dict)  # residual, inliers, iterations; "used": False when not applied

    def report(self) -> dict:
        """How the alignment went, JSON-serialisable (the run's ``report.json`` section ``continued``)."""
        est = self.filter_estimate
        dt, dr = pose_change(self.T_filter, self.T_prior_seq)
        R = self.T_prior_seq[:3, :3]
        return {"frames_localized": self.frames_localized, "converged_after_frames": self.converged_after,
                "particle_spread_m": round(est.spread_m, 4), "particle_spread_deg": round(est.spread_deg, 3),
                "cluster_mass": round(est.cluster_mass, 3), "scan_fit": round(est.fit, 3),
                "icp": self.icp, "icp_correction_m": round(dt, 4), "icp_correction_deg": round(dr, 3),
                "T_prior_seq": np.round(self.T_prior_seq, 6).tolist(),
                "translation_m": np.round(self.T_prior_seq[:3, 3], 4).tolist(),
                "rotation_deg": round(float(np.degrees(rotation_angle(self.T_prior_seq))), 3),
                "yaw_deg": round(math.degrees(math.atan2(R[1, 0], R[0, 0])), 3)}


@dataclass
class _Seen:
    """A localized frame: its pose in the recording's frame and its depth points (camera frame)."""

    T_seq_cam: np.ndarray
    points: np.ndarray


def align_settings(prior: PriorMap, particles: int = ALIGN_PARTICLES) -> FilterSettings:
    """The filter for an alignment: global 6-DoF, semantic where the prior has classes, else geometry; the
    endpoint σ at least ``SIGMA_VOXELS`` of the map's voxels (a surface point lies up to a half-diagonal from its
    voxel's centre: with σ = 5 cm on 10 cm voxels a correct pose would not count as explaining the scan)."""
    model = ObservationKind.SEMANTIC if prior.class_probs is not None else ObservationKind.GEOMETRY
    base = FilterSettings()
    sigma = max(base.likelihood.sigma, SIGMA_VOXELS * prior.resolution)
    return FilterSettings(particles=particles, mode=MotionMode.SIX_DOF, model=model,
                          likelihood=replace(base.likelihood, sigma=sigma), sigma_max=max(base.sigma_max, 2 * sigma))


def align_recording(prior: PriorMap, frames: Iterable[tuple[Frame, np.ndarray]], *,
                    segment: SegmentFn | None = None, settings: FilterSettings | None = None,
                    max_frames: int = ALIGN_MAX_FRAMES, settle: int = SETTLE_FRAMES, points: int = DEFAULT_POINTS,
                    seed: int = 0, icp: bool = True, surface: np.ndarray | None = None, min_depth: float = 0.1,
                    max_depth: float = 8.0) -> Alignment:
    """Localize the first frames ``(frame, T_seq_cam)`` of a recording in ``prior`` (global initialisation, the
    recording's own relative motion between updates) until the filter has converged and run ``settle`` more
    frames; the transform from the recording's frame to the prior's, refined by ICP against ``surface`` (the
    prior's finest surface points, e.g. a point map's; default its occupied voxel centres). A ConfigError when
    the filter does not converge within ``max_frames``."""
    compile_kernels()
    settings = settings or align_settings(prior)
    pf = ParticleFilter(prior, settings, seed=seed)
    rng = np.random.default_rng([seed, 0xA11])
    seen: list[_Seen] = []
    last: np.ndarray | None = None
    converged_at: int | None = None
    est = None
    for frame, T_seq in frames:
        if len(seen) >= max_frames:
            break
        T_seq = np.asarray(T_seq, np.float64)
        semantics = segment(frame) if segment is not None else None
        scan = make_scan(frame.depth, frame.intrinsics, semantics, resolution=prior.resolution, max_points=points,
                         rng=rng, num_classes=prior.num_classes, min_depth=min_depth, max_depth=max_depth)
        if not pf.initialised:
            pf.init_global()
            u = np.eye(4)
        else:
            u = invert_pose(last) @ T_seq
        last = T_seq
        est = pf.step(u, scan)
        stride = max(1, round(math.sqrt(frame.depth.size / 40_000)))
        seen.append(_Seen(T_seq, backproject(frame.depth, frame.intrinsics, min_depth=min_depth,
                                             max_depth=max_depth, stride=stride)[0]))
        if est.converged and converged_at is None:
            converged_at = len(seen)
        elif not est.converged:
            converged_at = None  # (a convergence lost again does not count)
        if converged_at is not None and len(seen) - converged_at >= settle:
            break
    if est is None:
        raise ConfigError("no frame with a pose to localize in the prior map")
    if converged_at is None or not est.converged:
        raise ConfigError(f"the first {len(seen)} frames could not be localized in the prior map (particle spread "
                          f"{est.spread_m:.2f} m / {est.spread_deg:.1f}°, {100 * est.fit:.0f}% of the scan on the "
                          "map): does the recording start where the prior map was mapped?")
    T_filter = est.T_world_cam @ invert_pose(seen[-1].T_seq_cam)
    target = prior.centers if surface is None else surface
    T, icp_info = (refine_icp(target, prior.resolution, T_filter, seen[-ICP_FRAMES:]) if icp
                   else (T_filter, {"used": False}))
    return Alignment(T, len(seen), converged_at, est, T_filter, icp_info)


def _surface(surface: np.ndarray, near: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
    """The surface points within ``radius`` of the box of the points ``near`` and their unit normals (smallest
    principal axis over ``NORMAL_NEIGHBOURS`` neighbours)."""
    centers = np.asarray(surface, np.float64)
    lo, hi = near.min(axis=0) - radius, near.max(axis=0) + radius
    box = _voxel_filter(centers[((centers >= lo) & (centers <= hi)).all(axis=1)], SURFACE_CELL_M)
    if len(box) < NORMAL_NEIGHBOURS:
        return box, np.zeros_like(box)
    tree = cKDTree(box)
    _, nb = tree.query(box, k=NORMAL_NEIGHBOURS)
    local = box[nb] - box[nb].mean(axis=1, keepdims=True)
    cov = np.einsum("nki,nkj->nij", local, local)
    _, vecs = np.linalg.eigh(cov)
    return box, vecs[:, :, 0]


def _voxel_filter(points: np.ndarray, size: float) -> np.ndarray:
    """One point (the first) per cell of ``size``."""
    if len(points) == 0:
        return points
    cells = np.floor(points / size).astype(np.int64)
    cells -= cells.min(axis=0)
    dims = cells.max(axis=0) + 1
    _, first = np.unique((cells[:, 0] * dims[1] + cells[:, 1]) * dims[2] + cells[:, 2], return_index=True)
    return points[np.sort(first)]


def refine_icp(surface: np.ndarray, res: float, T_start: np.ndarray, seen: list[_Seen]) -> tuple[np.ndarray, dict]:
    """Point-to-plane ICP (coarse to fine, in steps of the map's resolution ``res``) of the frames' depth points,
    placed by ``T_start`` and their poses, against the prior's ``surface`` points; the refined transform and the
    fit (RMS point-to-plane residual, share of points matched). A correction beyond ``ICP_MAX_CORRECTION_*`` is
    refused (the start is kept)."""
    src = np.concatenate([transform_points(s.T_seq_cam, s.points) for s in seen])
    src = _voxel_filter(src, min(res / 2, 0.02))
    if len(src) > ICP_MAX_POINTS:
        src = src[np.random.default_rng(0).choice(len(src), ICP_MAX_POINTS, replace=False)]
    tgt, normals = _surface(surface, transform_points(T_start, src), ICP_STAGES_VOXELS[0] * res)
    if len(tgt) < NORMAL_NEIGHBOURS:
        return T_start, {"used": False, "why": "too few map voxels near the frames"}
    tree = cKDTree(tgt)
    T = T_start.copy()
    rms = inliers = 0.0
    iterations = 0
    for stage in ICP_STAGES_VOXELS:
        for _ in range(ICP_ITERATIONS):
            step, rms, inliers = _icp_step(transform_points(T, src), tree, tgt, normals, stage * res)
            if step is None:
                break
            T = step @ T
            iterations += 1
            if np.linalg.norm(step[:3, 3]) < 1e-4 and rotation_angle(step) < 1e-4:
                break
    dt, dr = pose_change(T_start, T)
    info = {"used": True, "iterations": iterations, "rms_residual_m": round(float(rms), 5),
            "inlier_fraction": round(float(inliers), 4), "source_points": len(src)}
    if dt > ICP_MAX_CORRECTION_M or dr > ICP_MAX_CORRECTION_DEG:
        return T_start, {**info, "used": False, "why": f"correction {dt:.3f} m / {dr:.2f}° too large"}
    return T, info


def _icp_step(src: np.ndarray, tree: cKDTree, tgt: np.ndarray, normals: np.ndarray, max_dist: float
              ) -> tuple[np.ndarray | None, float, float]:
    """One linearised point-to-plane step: the small motion (4, 4) moving ``src`` onto the planes of its nearest
    target voxels within ``max_dist``; with the RMS residual and the share of points matched."""
    dist, idx = tree.query(src, distance_upper_bound=max_dist)
    ok = np.isfinite(dist)
    if ok.sum() < 6:
        return None, 0.0, 0.0
    p, q, n = src[ok], tgt[idx[ok]], normals[idx[ok]]
    r = np.einsum("ij,ij->i", p - q, n)
    A = np.concatenate([np.cross(p, n), n], axis=1)
    x = np.linalg.lstsq(A.T @ A + 1e-9 * np.eye(6), -A.T @ r, rcond=None)[0]
    from scipy.spatial.transform import Rotation

    step = make_pose(Rotation.from_rotvec(x[:3]).as_matrix(), x[3:])
    return step, float(np.sqrt(np.mean(r * r))), float(ok.mean())
