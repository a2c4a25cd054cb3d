"""Monte-Carlo localization (Dellaert et al. 1999) of a camera in a prior semantic map.

One update (:meth:`ParticleFilter.step`): move every particle by the relative motion with noise
(:mod:`~semmap.localization.motion`), weight it by the scan (:mod:`~semmap.localization.observation`),
resample with the low-variance sampler when the effective sample size drops, inject particles drawn from the
map's free space when the likelihood falls faster than its long-term average (augmented MCL, *Probabilistic
Robotics* Table 8.3: recovery from kidnapping), and report the pose of the strongest cluster with its covariance
and whether the filter has converged.  All per-particle work is array code or numba kernels.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.spatial.transform import Rotation

from semmap.errors import ConfigError
from semmap.limits import check, check_particles
from semmap.localization import _kernels as kern
from semmap.localization.motion import GroundTilt, MotionMode, MotionNoise, heading
from semmap.localization.observation import LikelihoodParams, ObservationKind, Scan, fit, score
from semmap.localization.prior import PriorMap
from semmap.types import make_pose, rot_z

#: Coarse bins (metres, radians) in which the strongest mode of the particle set is looked for.
MODE_BIN_M, MODE_BIN_RAD = 0.25, math.radians(30)
#: Particles within these distances of the strongest mode form the cluster the estimate is taken from.
CLUSTER_RADIUS_M, CLUSTER_RADIUS_RAD = 0.5, math.radians(30)
#: The cluster's covariance is taken over at most this many of its particles (evenly spaced).
COVARIANCE_SAMPLES = 2000


@dataclass(frozen=True)
class FilterSettings:
    """Everything the particle filter needs besides the map (keyword construction; defaults as measured)."""

    particles: int = 2000
    mode: MotionMode = MotionMode.SIX_DOF
    model: ObservationKind = ObservationKind.SEMANTIC
    likelihood: LikelihoodParams = field(default_factory=LikelihoodParams)
    motion: MotionNoise = field(default_factory=MotionNoise)
    resample_ess: float = 0.5  # resample when the effective sample size falls below this fraction
    min_ess: float = 0.1  # adaptive tempering: one update may not shrink the effective sample size below this
    roughen: float = 0.5  # jitter after a tempered resampling, in units of the current endpoint σ
    sigma_max: float = 0.12  # annealing: the endpoint σ follows the cluster's spread between likelihood.sigma and this
    inject_slow: float = 0.02  # augmented MCL: long-term average rate
    inject_fast: float = 0.3  # ... short-term average rate
    inject_max: float = 0.25  # at most this fraction of the particles is replaced per update
    converged_m: float = 0.10  # converged: the cluster's position std below this ...
    converged_deg: float = 5.0  # ... its rotation std below this ...
    converged_mass: float = 0.9  # ... it holds this share of the weight ...
    converged_fit: float = 0.75  # ... and this share of the scan lies within likelihood.sigma of the map at its pose
    tracking_sigma_m: float = 0.10  # tracking initialisation: spread around the given pose
    tracking_sigma_deg: float = 5.0
    pitch_range_deg: tuple[float, float] = (-45.0, 15.0)  # 6-DoF global initialisation: camera pitch prior
    roll_sigma_deg: float = 5.0  # ... and roll prior
    height_margin_m: float = 0.3  # 6-DoF global initialisation: camera between floor and ceiling by this margin

    def __post_init__(self) -> None:
        check("particles", self.particles)
        if not 0.0 < self.resample_ess <= 1.0:
            raise ConfigError(f"resample_ess must be in (0, 1], got {self.resample_ess}")
        if not 0.0 <= self.min_ess < 1.0:
            raise ConfigError(f"min_ess must be in [0, 1), got {self.min_ess}")
        if not 0.0 <= self.inject_max < 1.0:
            raise ConfigError(f"inject_max must be in [0, 1), got {self.inject_max}")


@dataclass(frozen=True)
class PoseEstimate:
    """The filter's belief after one update: the pose of its strongest cluster, that cluster's covariance
    (6x6 over position and rotation vector in the world frame, m² and rad²), its spread, and the set's state."""

    T_world_cam: np.ndarray  # (4, 4)
    covariance: np.ndarray  # (6, 6)
    spread_m: float  # sqrt of the largest position variance of the cluster
    spread_deg: float  # sqrt of the largest rotation variance of the cluster, degrees
    cluster_mass: float  # share of the weight in the cluster
    fit: float  # share of the scan's points within likelihood.sigma of an occupied voxel at the estimated pose
    converged: bool
    n_eff: float  # effective sample size before resampling
    resampled: bool
    injected: int  # particles replaced by samples from free space
    tempering: float  # share of the scan's log-likelihood applied (1 unless it would have collapsed the set)
    sigma: float  # endpoint σ of the likelihood field used in this update (annealed with the spread), metres
    ms: dict[str, float]


class ParticleFilter:
    """Particles over camera poses in a :class:`PriorMap`: (R, t) in 6-DoF mode, (x, y, yaw) in ground mode."""

    def __init__(self, prior: PriorMap, settings: FilterSettings | None = None, *, seed: int = 0) -> None:
        self.prior = prior
        self.settings = settings or FilterSettings()
        self.rng = np.random.default_rng([seed, 0x3C1])
        n = self.settings.particles
        check_particles(n)  # the memory of the set, before any of it is allocated
        self.R = np.tile(np.eye(3), (n, 1, 1))
        self.t = np.zeros((n, 3))
        self.yaw = np.zeros(n)  # ground mode state with t[:, :2]
        self.logw = np.zeros(n)
        self.tilt: GroundTilt | None = None
        self._scores = np.zeros(n)
        self._w_slow = self._w_fast = 0.0
        self.sigma = self.settings.sigma_max
        self.converged = False
        self._free = np.flatnonzero(prior.free_clear)
        if self._free.size == 0:
            raise ConfigError("the prior map has no free space with clearance (global initialisation impossible)")
        self._free_centers = prior.cell_centers(self._free)
        self.initialised = False

    @property
    def n(self) -> int:
        return self.settings.particles

    @property
    def ground(self) -> bool:
        return self.settings.mode == MotionMode.GROUND

    # ------------------------------------------------------------------ initialisation
    def init_global(self, tilt: GroundTilt | None = None) -> None:
        """Particles spread uniformly over the map's free space (within the floor-to-ceiling band, or at the
        known height in ground mode), headings uniform, equal weights."""
        self._set_tilt(tilt)
        self._sample_free(np.arange(self.n))
        self.logw[:] = 0.0
        self.sigma = self.settings.sigma_max
        self.converged = False
        self.initialised = True

    def init_tracking(self, T_world_cam: np.ndarray, tilt: GroundTilt | None = None) -> None:
        """Particles normally distributed around a known pose (``tracking_sigma_m``, ``tracking_sigma_deg``)."""
        self._set_tilt(tilt)
        s = self.settings
        T = np.asarray(T_world_cam, np.float64)
        if self.ground:
            self.t[:, :2] = T[:2, 3] + self.rng.normal(0.0, s.tracking_sigma_m, (self.n, 2))
            self.yaw[:] = heading(T[:3, :3]) + self.rng.normal(0.0, math.radians(s.tracking_sigma_deg), self.n)
            self._ground_poses()
        else:
            self.t[:] = T[:3, 3] + self.rng.normal(0.0, s.tracking_sigma_m, (self.n, 3))
            w = self.rng.normal(0.0, math.radians(s.tracking_sigma_deg), (self.n, 3))
            self.R[:] = T[:3, :3] @ Rotation.from_rotvec(w).as_matrix()
        self.logw[:] = 0.0
        self.sigma = _annealed_sigma(s.tracking_sigma_m, s.likelihood.sigma, s.sigma_max)
        self.converged = False
        self.initialised = True

    def _set_tilt(self, tilt: GroundTilt | None) -> None:
        if self.ground and tilt is None:
            raise ConfigError("ground mode needs the camera's height and tilt (a GroundTilt) for every update")
        self.tilt = tilt

    def _sample_free(self, idx: np.ndarray) -> None:
        """Draw the particles ``idx`` uniformly from the free space with clearance."""
        if idx.size == 0:
            return
        s, res = self.settings, self.prior.resolution
        centers = self._free_centers
        if self.ground:
            layer = np.abs(centers[:, 2] - self.tilt.height) <= res
            pool = centers[layer] if layer.any() else centers
        else:
            lo, hi = self.prior.floor_z + s.height_margin_m, self.prior.ceiling_z - s.height_margin_m
            band = (centers[:, 2] >= lo) & (centers[:, 2] <= hi)
            pool = centers[band] if band.any() else centers
        pos = pool[self.rng.integers(0, len(pool), idx.size)] + self.rng.uniform(-res / 2, res / 2, (idx.size, 3))
        yaw = self.rng.uniform(-math.pi, math.pi, idx.size)
        if self.ground:
            self.t[idx, :2] = pos[:, :2]
            self.yaw[idx] = yaw
            self._ground_poses(idx)
            return
        self.t[idx] = pos
        pitch = np.radians(self.rng.uniform(*s.pitch_range_deg, idx.size))
        roll = np.radians(self.rng.normal(0.0, s.roll_sigma_deg, idx.size))
        self.R[idx] = _camera_rotations(yaw, pitch, roll)

    def _ground_poses(self, idx: np.ndarray | slice = slice(None)) -> None:
        """Full poses of ground-mode particles from (x, y, yaw) and the known height and tilt."""
        self.R[idx] = rot_z(self.yaw[idx]) @ self.tilt.tilt
        self.t[idx, 2] = self.tilt.height

    # ------------------------------------------------------------------ one update
    def step(self, u: np.ndarray, scan: Scan, tilt: GroundTilt | None = None) -> PoseEstimate:
        """Predict with the relative camera motion ``u`` (4, 4) since the last update, weight by ``scan``,
        resample and inject as needed; the estimate after the update."""
        if not self.initialised:
            raise ConfigError("initialise the particle filter (init_global or init_tracking) before stepping")
        t0, c0 = time.perf_counter(), time.process_time()
        self.predict(u, tilt)
        t1 = time.perf_counter()
        avg_likelihood, tempering = self.correct(scan)
        t2 = time.perf_counter()
        n_eff, resampled, injected = self._resample_and_inject(avg_likelihood)
        t3 = time.perf_counter()
        est = self.estimate(scan)
        sigma = self.sigma
        s = self.settings
        self.sigma = _annealed_sigma(est.spread_m if est.cluster_mass >= 0.5 else s.sigma_max, s.likelihood.sigma,
                                     s.sigma_max)
        if resampled and tempering < 1.0:
            self._roughen(sigma)  # after the estimate: the jitter must not feed back into the annealed σ
        self.converged = est.converged
        t4 = time.perf_counter()
        ms = {"motion": (t1 - t0) * 1e3, "weights": (t2 - t1) * 1e3, "resample": (t3 - t2) * 1e3,
              "estimate": (t4 - t3) * 1e3, "total": (t4 - t0) * 1e3,
              "cpu": (time.process_time() - c0) * 1e3}  # CPU time of all threads: less sensitive to other jobs
        return PoseEstimate(est.T_world_cam, est.covariance, est.spread_m, est.spread_deg, est.cluster_mass,
                            est.fit, est.converged, n_eff, resampled, injected, tempering, sigma, ms)

    def predict(self, u: np.ndarray, tilt: GroundTilt | None = None) -> None:
        """Motion update: every particle moved by ``u`` (the camera's motion in its own frame) with noise."""
        u = np.asarray(u, np.float64)
        sig_t, sig_r = self.settings.motion.sigmas(u)
        if self.ground:
            if tilt is None:
                raise ConfigError("ground mode needs the camera's height and tilt for every update")
            # the motion seen from a particle at heading 0: planar displacement and turn, same for every particle
            moved = self.tilt.tilt @ u[:3, :3]
            d = self.tilt.tilt @ u[:3, 3]
            c, s = np.cos(self.yaw), np.sin(self.yaw)
            nt = self.rng.normal(0.0, sig_t, (self.n, 2))
            self.t[:, 0] += c * d[0] - s * d[1] + nt[:, 0]
            self.t[:, 1] += s * d[0] + c * d[1] + nt[:, 1]
            self.yaw += heading(moved) + self.rng.normal(0.0, sig_r, self.n)
            self.yaw = (self.yaw + math.pi) % (2 * math.pi) - math.pi
            self.tilt = tilt
            self._ground_poses()
            return
        noise = np.empty((self.n, 6))
        noise[:, :3] = self.rng.normal(0.0, sig_t / math.sqrt(3), (self.n, 3))
        noise[:, 3:] = self.rng.normal(0.0, sig_r / math.sqrt(3), (self.n, 3))
        kern.propagate_6dof(self.R, self.t, np.ascontiguousarray(u[:3, :3]), np.ascontiguousarray(u[:3, 3]), noise)

    def correct(self, scan: Scan) -> tuple[float, float]:
        """Observation update: add each particle's log-likelihood of ``scan`` (tempered, see
        :func:`tempering`); returns the particles' average likelihood per point (augmented MCL's w_avg) and the
        tempering applied."""
        s = self.settings
        score(s.model, self.prior, self.R, self.t, scan, replace(s.likelihood, sigma=self.sigma), self._scores)
        # tempering guards a spread-out set; once converged the scan is applied in full (plain MCL)
        beta = 1.0 if self.converged else tempering(self.logw, self._scores, s.min_ess * self.n)
        self.logw += beta * self._scores
        if s.model == ObservationKind.COSINE:
            return float(np.exp(self._scores).mean()), beta
        return float(np.exp(self._scores / s.likelihood.effective_points).mean()), beta

    def weights(self) -> np.ndarray:
        """Normalised weights (N,)."""
        w = np.exp(self.logw - self.logw.max())
        return w / w.sum()

    def _resample_and_inject(self, avg_likelihood: float) -> tuple[float, bool, int]:
        s = self.settings
        w = self.weights()
        n_eff = float(1.0 / np.sum(w * w))
        resampled = n_eff < s.resample_ess * self.n
        if resampled:
            self._resample(w)
        # augmented MCL: inject free-space samples when the short-term likelihood falls below the long-term one
        if self._w_slow == 0.0:
            self._w_slow = self._w_fast = avg_likelihood
        self._w_slow += s.inject_slow * (avg_likelihood - self._w_slow)
        self._w_fast += s.inject_fast * (avg_likelihood - self._w_fast)
        frac = min(s.inject_max, max(0.0, 1.0 - self._w_fast / max(self._w_slow, 1e-300)))
        k = int(self.rng.binomial(self.n, frac)) if frac > 0 else 0
        if k:
            idx = self.rng.choice(self.n, k, replace=False)
            self._sample_free(idx)
            self.logw[idx] = np.log(np.mean(np.exp(self.logw - self.logw.max()))) + self.logw.max()
        return n_eff, resampled, k

    def _roughen(self, sigma: float) -> None:
        """Jitter every particle by the current endpoint σ (and σ per metre in angle): when the scan is sharper than
        the particle set (tempering was needed), resampled copies would otherwise only crawl towards the peak."""
        s = self.settings
        sig = sigma * s.roughen
        if sig <= 0:
            return
        if self.ground:
            self.t[:, :2] += self.rng.normal(0.0, sig, (self.n, 2))
            self.yaw += self.rng.normal(0.0, sig, self.n)
            self._ground_poses()
            return
        self.t += self.rng.normal(0.0, sig / math.sqrt(3), (self.n, 3))
        self.R = self.R @ Rotation.from_rotvec(self.rng.normal(0.0, sig / math.sqrt(3), (self.n, 3))).as_matrix()

    def _resample(self, w: np.ndarray) -> None:
        """Low-variance (systematic) resampling (*Probabilistic Robotics* Table 4.4)."""
        positions = (self.rng.random() + np.arange(self.n)) / self.n
        idx = np.minimum(np.searchsorted(np.cumsum(w), positions), self.n - 1)
        self.R = self.R[idx]
        self.t = self.t[idx]
        self.yaw = self.yaw[idx]
        self.logw[:] = 0.0

    # ------------------------------------------------------------------ estimate
    def estimate(self, scan: Scan | None = None) -> PoseEstimate:
        """Pose of the strongest cluster (weighted mean position, chordal mean rotation) with its covariance;
        converged when the cluster is tight, holds most of the weight and (given the ``scan``) explains it."""
        s = self.settings
        w = self.weights()
        head = heading(self.R)
        # strongest mode on a coarse (x, y, heading) histogram, then every particle near it
        cells = np.floor(self.t[:, :2] / MODE_BIN_M).astype(np.int64)
        hbin = np.floor((head + math.pi) / MODE_BIN_RAD).astype(np.int64)
        cells -= cells.min(axis=0)
        _, inv = np.unique((cells[:, 0] * (cells[:, 1].max() + 1) + cells[:, 1]) * 16 + hbin, return_inverse=True)
        best = int(np.argmax(np.bincount(inv, weights=w)))
        sel = inv == best
        ws = w[sel] / w[sel].sum()
        seed_pos = ws @ self.t[sel]
        seed_head = math.atan2(ws @ np.sin(head[sel]), ws @ np.cos(head[sel]))
        dpos = np.linalg.norm(self.t - seed_pos, axis=1)
        dhead = np.abs((head - seed_head + math.pi) % (2 * math.pi) - math.pi)
        cluster = (dpos <= CLUSTER_RADIUS_M) & (dhead <= CLUSTER_RADIUS_RAD)
        mass = float(w[cluster].sum())
        wc = w[cluster] / max(mass, 1e-300)
        mean_t = wc @ self.t[cluster]
        U, _, Vt = np.linalg.svd(np.einsum("n,nij->ij", wc, self.R[cluster]))
        mean_R = U @ np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))]) @ Vt
        # covariance from at most COVARIANCE_SAMPLES evenly taken cluster members (weights renormalised)
        members = np.flatnonzero(cluster)
        take = slice(None, None, max(1, len(members) // COVARIANCE_SAMPLES))
        members, wm = members[take], wc[take] / wc[take].sum()
        d = np.empty((len(members), 6))
        d[:, :3] = self.t[members] - mean_t
        d[:, 3:] = Rotation.from_matrix(np.einsum("ji,njk->nik", mean_R, self.R[members])).as_rotvec() @ mean_R.T
        cov = (d * wm[:, None]).T @ d
        spread_m = float(np.sqrt(max(np.linalg.eigvalsh(cov[:3, :3]).max(), 0.0)))
        spread_deg = float(np.degrees(np.sqrt(max(np.linalg.eigvalsh(cov[3:, 3:]).max(), 0.0))))
        T = make_pose(mean_R, mean_t)
        fitted = fit(self.prior, T, scan, s.likelihood.sigma) if scan is not None and len(scan) else 0.0
        converged = mass >= s.converged_mass and spread_m < s.converged_m and spread_deg < s.converged_deg \
            and (scan is None or fitted >= s.converged_fit)
        return PoseEstimate(T, cov, spread_m, spread_deg, mass, fitted, bool(converged),
                            float(1.0 / np.sum(w * w)), False, 0, 1.0, self.sigma, {})

    def snapshot(self, max_particles: int = 2000) -> np.ndarray:
        """(n, 4) float32 x, y, z, heading of (at most ``max_particles``, evenly taken) particles, for plots."""
        step = max(1, self.n // max_particles)
        return np.concatenate([self.t[::step], heading(self.R[::step])[:, None]], axis=1).astype(np.float32)


#: Annealed σ values are rounded to this many steps per doubling (the likelihood tables are cached per σ).
SIGMA_STEPS_PER_DOUBLING = 4


def _annealed_sigma(spread: float, sigma_min: float, sigma_max: float) -> float:
    """Endpoint σ for the next update: the cluster's spread clipped to [sigma_min, sigma_max], rounded to a
    geometric ladder from sigma_min.  Annealing (Deutscher et al. 2000): a wide likelihood while the set is spread
    keeps particles near the truth alive; it sharpens as the set concentrates."""
    if sigma_max <= sigma_min:
        return sigma_min
    steps = round(SIGMA_STEPS_PER_DOUBLING * math.log2(min(max(spread, sigma_min), sigma_max) / sigma_min))
    return min(sigma_min * 2.0 ** (steps / SIGMA_STEPS_PER_DOUBLING), sigma_max)


def _ess(logw: np.ndarray) -> float:
    w = np.exp(logw - logw.max())
    return float(w.sum() ** 2 / np.sum(w * w))


#: Bisection steps of the tempering search (the share is found to 2^-12).
TEMPERING_STEPS = 12


def tempering(logw: np.ndarray, scores: np.ndarray, min_ess: float) -> float:
    """Largest β in (0, 1] for which the weights ``logw + β · scores`` keep an effective sample size of at least
    ``min_ess`` (or that of ``logw`` alone, if smaller): adaptive tempering, so that one sharp scan cannot collapse
    a spread-out particle set onto the few particles that happen to lie nearest the truth."""
    floor = min(min_ess, _ess(logw))
    if _ess(logw + scores) >= floor:
        return 1.0
    lo, hi = 0.0, 1.0
    for _ in range(TEMPERING_STEPS):
        mid = 0.5 * (lo + hi)
        if _ess(logw + mid * scores) >= floor:
            lo = mid
        else:
            hi = mid
    return max(lo, 2.0 ** -TEMPERING_STEPS)


def _camera_rotations(yaw: np.ndarray, pitch: np.ndarray, roll: np.ndarray) -> np.ndarray:
    """R_world_cam (N, 3, 3) of cameras looking along (yaw, pitch) (z up, camera y down) rolled about the axis."""
    f = np.stack([np.cos(pitch) * np.cos(yaw), np.cos(pitch) * np.sin(yaw), np.sin(pitch)], 1)
    x = np.stack([np.sin(yaw), -np.cos(yaw), np.zeros_like(yaw)], 1)  # f x z_up, normalised
    y = np.cross(f, x)
    c, s = np.cos(roll)[:, None], np.sin(roll)[:, None]
    return np.stack([c * x + s * y, -s * x + c * y, f], 2)
