"""Motion like a hand: re-time a smooth simulated path the way a person scans, and add what hands do.

The trajectory builders (:mod:`semmap.sim.trajectory`) give smooth, evenly paced paths, two to four times faster
than 7-Scenes' hand-held sequences and without their jitter. :func:`handheld` turns such a path into a hand-held
one (all randomness from the trajectory's generator):

- **pace**: the camera moves along the base path at a rate that wanders (log-normal, ``rate_sigma``, correlation
  time ``rate_time_s``) around the 7-Scenes medians of linear and angular speed (``speed_m_s``,
  ``turn_deg_s``), now and then pausing (``pauses_per_min``); at the path's end it turns back along it;
- **fast turns**: now and then (``turns_per_min``) the camera swings ``turn_deg`` about the vertical at up to
  ``turn_peak_deg_s``, holds, and swings back;
- **bare walls**: now and then (``walls_per_min``) it turns to a nearby stretch of bare wall (found by casting
  rays; every ray of a small cone hits the wall class) and looks at it for ``wall_hold_s`` seconds;
- **jitter**: nearly white shake of the position and orientation in the camera frame, scaled so that its
  high-pass part (the pose minus its Gaussian smoothing over 2 frames) has 7-Scenes' standard deviation per axis.

The targets were measured on ``../shared/data/7scenes-redkitchen`` (600 frames at 30 Hz, ground-truth poses;
``benchmarks/bench_realism_camera.py`` measures them again): per-frame linear speed quantiles 5/25/50/75/95 %
0.031/0.160/0.244/0.321/0.452 m/s, angular speed 1.7/7.1/12.6/17.8/24.8 deg/s; smoothed over 4 frames the
medians are 0.226 m/s and 8.1 deg/s; high-pass jitter 2.4/1.9/1.2 mm (camera x/y/z) and 0.14/0.13/0.14 deg,
nearly white (Gaussian correlation 0.65 and 0.8 frames).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.ndimage import gaussian_filter1d
from scipy.spatial.transform import Rotation, Slerp

from semmap.errors import SimulationError
from semmap.labels import INDOOR_LABELS

PRESETS: tuple[str, ...] = ("clean", "kinect", "hard")
#: 7-Scenes redkitchen ground truth (see the module docstring): per-frame speed quantiles at 5/25/50/75/95 %.
SEVEN_SCENES_SPEED_Q = (0.031, 0.160, 0.244, 0.321, 0.452)
SEVEN_SCENES_ANGULAR_Q_DEG = (1.7, 7.1, 12.6, 17.8, 24.8)
QUANTILES = (5, 25, 50, 75, 95)
#: Combined motion (linear + angular, each in its target median) per second at the median pace: 2 would hold
#: when both medians were met at once; a little more because the base paths' mix of the two varies.
PACE = 2.6
#: Spread (std of the logarithm) of the jitter's slowly varying amplitude: 7-Scenes' per-frame angular speed
#: reaches down to 1.7 deg/s (5 %), which an even shake of its size would never allow.
JITTER_BURSTS = 1.0
#: A wall look is left out when the view would have to turn further than this from the path's view at any time.
WALL_MAX_TURN_DEG = 120.0
#: High-pass filter of the jitter measure (Gaussian sigma, frames).
JITTER_HP_FRAMES = 2.0


@dataclass(frozen=True)
class MotionParams:
    """How the camera is carried; ``hand=False`` keeps the builders' smooth path with its small shake."""

    hand: bool = False
    speed_m_s: float = 0.226  # median smoothed linear speed
    turn_deg_s: float = 8.1  # median smoothed angular speed
    rate_sigma: float = 0.45  # spread of the pace (std of its logarithm)
    rate_time_s: float = 1.5  # correlation time of the pace
    pauses_per_min: float = 0.0  # the hand stops for 0.5-1.5 s (the pace drops to a tenth)
    turns_per_min: float = 0.0
    turn_deg: tuple[float, float] = (50.0, 90.0)
    turn_peak_deg_s: float = 90.0
    walls_per_min: float = 0.0
    wall_hold_s: tuple[float, float] = (1.5, 3.0)
    jitter_mm: tuple[float, float, float] = (2.4, 1.9, 1.2)
    jitter_deg: tuple[float, float, float] = (0.14, 0.13, 0.14)
    jitter_sigma_frames: tuple[float, float] = (0.65, 0.8)  # correlation of position / rotation jitter

    def __post_init__(self) -> None:
        if not (self.speed_m_s > 0 and self.turn_deg_s > 0 and self.rate_time_s > 0 and self.turn_peak_deg_s > 0):
            raise SimulationError("hand motion speeds and times must be positive")
        if min(self.rate_sigma, self.turns_per_min, self.walls_per_min, self.pauses_per_min) < 0:
            raise SimulationError("hand motion spreads and event rates must be non-negative")


_PRESETS: dict[str, MotionParams] = {
    "clean": MotionParams(),
    "kinect": MotionParams(hand=True, pauses_per_min=2.0, turns_per_min=0.5, turn_peak_deg_s=45.0, walls_per_min=0.75,
                           wall_hold_s=(1.0, 2.5)),
    "hard": MotionParams(hand=True, speed_m_s=0.36, turn_deg_s=13.0, rate_sigma=0.4, pauses_per_min=2.0,
                         turns_per_min=4.0,
                         turn_peak_deg_s=140.0, walls_per_min=3.0, wall_hold_s=(2.0, 4.0),
                         jitter_mm=(3.6, 2.9, 1.8), jitter_deg=(0.21, 0.2, 0.21)),
}


def motion_params(preset: str) -> MotionParams:
    """The hand motion of ``preset`` (clean: the builders' own smooth paths; kinect: 7-Scenes-like; hard)."""
    if preset not in _PRESETS:
        raise SimulationError(f"unknown motion preset {preset!r}; choose one of {', '.join(PRESETS)}")
    return _PRESETS[preset]


def speed_stats(poses: np.ndarray, fps: float = 30.0) -> dict[str, list[float]]:
    """Per-frame linear (m/s) and angular (deg/s) speed quantiles (5/25/50/75/95 %) of (N, 4, 4) poses."""
    v, w = frame_speeds(poses, fps)
    return {"speed_q": [round(float(x), 4) for x in np.percentile(v, QUANTILES)],
            "angular_q_deg": [round(float(x), 3) for x in np.degrees(np.percentile(w, QUANTILES))]}


def frame_speeds(poses: np.ndarray, fps: float = 30.0) -> tuple[np.ndarray, np.ndarray]:
    """Linear (m/s) and angular (rad/s) speed between consecutive poses."""
    poses = np.asarray(poses, np.float64)
    v = np.linalg.norm(np.diff(poses[:, :3, 3], axis=0), axis=1) * fps
    rel = np.einsum("nji,njk->nik", poses[:-1, :3, :3], poses[1:, :3, :3])
    w = np.linalg.norm(Rotation.from_matrix(rel).as_rotvec(), axis=1) * fps
    return v, w


def jitter_stats(poses: np.ndarray) -> dict[str, list[float]]:
    """High-pass jitter of (N, 4, 4) poses: std per camera axis of position (mm) and rotation (deg)."""
    poses = np.asarray(poses, np.float64)
    pos = poses[:, :3, 3]
    hp = np.einsum("nji,nj->ni", poses[:, :3, :3], pos - gaussian_filter1d(pos, JITTER_HP_FRAMES, axis=0,
                                                                           mode="nearest"))
    quat = _continuous_quats(poses[:, :3, :3])
    smooth = gaussian_filter1d(quat, JITTER_HP_FRAMES, axis=0, mode="nearest")
    smooth /= np.linalg.norm(smooth, axis=1, keepdims=True)
    rot = (Rotation.from_quat(smooth).inv() * Rotation.from_matrix(poses[:, :3, :3])).as_rotvec()
    return {"jitter_mm": [round(float(x), 3) for x in 1000 * hp.std(0)],
            "jitter_deg": [round(float(x), 4) for x in np.degrees(rot.std(0))]}


def handheld(base: np.ndarray, rng: np.random.Generator, params: MotionParams, fps: float,
             raycaster=None, tri_class: np.ndarray | None = None) -> np.ndarray:
    """Hand-held version of the smooth (N, 4, 4) path ``base`` taken at ``fps`` (see the module docstring);
    ``raycaster`` (open3d) and the scene's per-triangle ``tri_class`` let it find bare walls to look at."""
    n = len(base)
    if n < 2:
        return np.array(base, np.float64)
    t = np.arange(n) / fps
    tau = _paced_times(base, rng, params, fps)
    poses = _interpolate(base, t, tau)
    poses = _add_turns(poses, rng, params, fps)
    if raycaster is not None and tri_class is not None:
        poses = _add_wall_looks(poses, rng, params, fps, raycaster, tri_class)
    return _add_jitter(poses, rng, params)


# --------------------------------------------------------------------------------------------------
# pace
# --------------------------------------------------------------------------------------------------
def _paced_times(base: np.ndarray, rng: np.random.Generator, p: MotionParams, fps: float) -> np.ndarray:
    """Base-path time of each hand frame: the combined motion ``v / speed + w / turn`` advances at ``PACE r(t)``."""
    n = len(base)
    v, w = frame_speeds(base, fps)
    g = v / p.speed_m_s + w / math.radians(p.turn_deg_s)  # base motion per second, in target medians
    g = np.maximum(np.append(g, g[-1]), 0.05)
    rate = np.exp(p.rate_sigma * _ou(rng, n, p.rate_time_s * fps) - 0.5 * p.rate_sigma ** 2)
    t = np.arange(n) / fps
    for start in _event_starts(rng, p.pauses_per_min, t[-1], 2.0):
        rate *= 1.0 - 0.9 * _ramp(t, start, 0.3, float(rng.uniform(0.5, 1.5)))
    dt = 1.0 / fps
    end = (n - 1) * dt
    tau = np.zeros(n)
    pos, direction = 0.0, 1.0
    for k in range(1, n):
        step = min(PACE * rate[k - 1] / g[min(int(pos * fps + 0.5), n - 1)], 4.0) * dt
        pos += direction * step
        if pos > end:  # the path ends: walk back along it
            pos, direction = 2 * end - pos, -1.0
        elif pos < 0.0:
            pos, direction = -pos, 1.0
        tau[k] = pos
    return tau


def _ou(rng: np.random.Generator, n: int, corr_frames: float) -> np.ndarray:
    """Unit-variance AR(1) series of ``n`` steps with correlation time ``corr_frames``."""
    a = math.exp(-1.0 / max(corr_frames, 1e-6))
    eps = rng.standard_normal(n)
    x = np.empty(n)
    x[0] = eps[0]
    b = math.sqrt(1 - a * a)
    for k in range(1, n):
        x[k] = a * x[k - 1] + b * eps[k]
    return x


def _continuous_quats(R: np.ndarray) -> np.ndarray:
    """Quaternions (x, y, z, w) of rotations ``R`` with signs chosen so consecutive ones agree."""
    q = Rotation.from_matrix(R).as_quat()
    flip = np.cumsum(np.einsum("ij,ij->i", q[1:], q[:-1]) < 0) % 2 == 1
    q[1:][flip] *= -1
    return q


def _interpolate(base: np.ndarray, t: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """Poses of ``base`` (taken at times ``t``) at times ``tau``: linear in position, slerp in rotation."""
    out = np.tile(np.eye(4), (len(tau), 1, 1))
    out[:, :3, :3] = Slerp(t, Rotation.from_matrix(base[:, :3, :3]))(np.clip(tau, t[0], t[-1])).as_matrix()
    for k in range(3):
        out[:, k, 3] = np.interp(tau, t, base[:, k, 3])
    return out


# --------------------------------------------------------------------------------------------------
# events: fast turns and bare walls
# --------------------------------------------------------------------------------------------------
def _event_starts(rng: np.random.Generator, per_min: float, duration: float, gap: float) -> list[float]:
    """Start times of a Poisson process of ``per_min`` events a minute, at least ``gap`` s apart, in (1, duration)."""
    starts: list[float] = []
    if per_min <= 0:
        return starts
    s = float(rng.exponential(60.0 / per_min)) * 0.5 + 1.0
    while s < duration - gap:
        starts.append(s)
        s += gap + float(rng.exponential(60.0 / per_min))
    return starts


def _ramp(t: np.ndarray, start: float, ramp: float, hold: float, ramp_out: float | None = None) -> np.ndarray:
    """0 -> 1 (raised cosine over ``ramp`` s), 1 for ``hold`` s, 1 -> 0 again (over ``ramp_out`` s, default
    ``ramp``): the weight of an excursion."""
    up = np.clip((t - start) / ramp, 0.0, 1.0)
    down = np.clip((t - start - ramp - hold) / (ramp if ramp_out is None else ramp_out), 0.0, 1.0)
    return 0.5 - 0.5 * np.cos(np.pi * (up - down))


def _add_turns(poses: np.ndarray, rng: np.random.Generator, p: MotionParams, fps: float) -> np.ndarray:
    """Fast swings about the vertical (world z) that return to the path's view."""
    t = np.arange(len(poses)) / fps
    yaw = np.zeros(len(poses))
    for start in _event_starts(rng, p.turns_per_min, t[-1], 5.0):
        angle = math.radians(rng.uniform(*p.turn_deg)) * rng.choice([-1.0, 1.0])
        ramp = abs(angle) * math.pi / (2.0 * math.radians(p.turn_peak_deg_s))  # raised cosine peak = p.turn_peak
        yaw += angle * _ramp(t, start, ramp, float(rng.uniform(0.5, 1.5)))
    if not yaw.any():
        return poses
    out = poses.copy()
    Rz = Rotation.from_rotvec(np.stack([np.zeros_like(yaw), np.zeros_like(yaw), yaw], 1)).as_matrix()
    out[:, :3, :3] = Rz @ poses[:, :3, :3]
    return out


def _add_wall_looks(poses: np.ndarray, rng: np.random.Generator, p: MotionParams, fps: float, raycaster,
                    tri_class: np.ndarray) -> np.ndarray:
    """Stretches that turn to a bare wall nearby and look at it, then back to the path's view (the turn is split
    into heading and pitch, each unwrapped over the stretch, so it stays continuous while the path turns). The
    wall is sought from the middle of the stretch, then from its start; a stretch whose view would have to turn
    further than WALL_MAX_TURN_DEG from the path's at any time is left out."""
    t = np.arange(len(poses)) / fps
    out = poses.copy()
    for start in _event_starts(rng, p.walls_per_min, t[-1], 6.0):
        hold = float(rng.uniform(*p.wall_hold_s))
        k0 = int(start * fps)
        for k in (min(int((start + 0.5 + 0.5 * hold) * fps), len(poses) - 1), k0):
            target = _bare_wall_view(poses[k], raycaster, tri_class)
            turn = None if target is None else _wall_turn(out, t, start, hold, target, p, fps)
            if turn is not None:
                active, weight, dyaw, dpitch = turn
                about_z = Rotation.from_rotvec(np.outer(weight * dyaw, [0.0, 0.0, 1.0])).as_matrix()
                about_x = Rotation.from_rotvec(np.outer(weight * dpitch, [1.0, 0.0, 0.0])).as_matrix()
                out[active, :3, :3] = about_z @ out[active, :3, :3] @ about_x
                break
    return out


def _wall_turn(poses: np.ndarray, t: np.ndarray, start: float, hold: float, target: np.ndarray, p: MotionParams,
               fps: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """Frames, weights and the heading and pitch turns (radians) that make ``poses`` face ``target`` from
    ``start`` for ``hold`` seconds (raised-cosine ramps peaking at ``turn_peak_deg_s``), or None when too far."""
    k = int(start * fps)
    yaw_t, pitch_t = _heading(target[None, :, 2])
    yaw_all, pitch_all = _heading(poses[k:, :3, 2])
    turn = np.hypot(np.unwrap(np.angle(np.exp(1j * (yaw_t[0] - yaw_all)))), pitch_t[0] - pitch_all)

    def ramp_s(angle: float) -> float:  # a raised cosine turning ``angle`` peaks at turn_peak_deg_s
        return max(0.4, angle * math.pi / (2.0 * math.radians(p.turn_peak_deg_s)))

    ramp = ramp_s(float(turn[0]))
    back = min(round((start + ramp + hold) * fps) - k, len(turn) - 1)
    weight = _ramp(t, start, ramp, hold, ramp_s(float(turn[max(back, 0)])))
    active = np.flatnonzero(weight > 0)
    if len(active) == 0:
        return None
    yaw_c, pitch_c = _heading(poses[active, :3, 2])
    dyaw = np.unwrap(np.angle(np.exp(1j * (yaw_t - yaw_c))))
    if abs(dyaw[0]) > math.pi:
        dyaw -= 2 * math.pi * np.round(dyaw[0] / (2 * math.pi))
    if np.abs(dyaw).max() > math.radians(WALL_MAX_TURN_DEG):  # the path turns away meanwhile: no spinning
        return None
    return active, weight[active], dyaw, pitch_t - pitch_c


def _heading(forward: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Heading (about world z) and pitch (up positive) of (N, 3) viewing directions, radians."""
    f = np.atleast_2d(forward)
    return np.arctan2(f[:, 1], f[:, 0]), np.arcsin(np.clip(f[:, 2], -1.0, 1.0))


def _bare_wall_view(pose: np.ndarray, raycaster, tri_class: np.ndarray) -> np.ndarray | None:
    """Rotation of a camera at ``pose``'s position facing bare wall 0.6-3 m away (at least 80 % of a cone of rays
    on the wall), the one needing the smallest turn (at most 120 degrees); None when there is none."""
    import open3d as o3d

    wall = INDOOR_LABELS.id_of("wall")
    eye = pose[:3, 3]
    fwd = pose[:3, 2]
    yaw0 = math.atan2(fwd[1], fwd[0])
    yaws = yaw0 + np.radians(np.arange(-120, 121, 10.0))
    spread = np.radians(np.array([-12.0, -6.0, 0.0, 6.0, 12.0]))
    pitch = math.radians(-5.0)
    a = (yaws[:, None, None] + spread[None, :, None]) * np.ones((1, 1, 3))
    b = pitch + np.array([-0.12, 0.0, 0.12])[None, None, :] * np.ones_like(a)
    dirs = np.stack([np.cos(b) * np.cos(a), np.cos(b) * np.sin(a), np.sin(b)], -1).reshape(-1, 3)
    rays = np.concatenate([np.broadcast_to(eye, dirs.shape), dirs], 1).astype(np.float32)
    hit = raycaster.cast_rays(o3d.core.Tensor.from_numpy(np.ascontiguousarray(rays)))
    prim = hit["primitive_ids"].numpy().astype(np.int64)
    dist = hit["t_hit"].numpy()
    valid = (prim >= 0) & (prim < len(tri_class)) & np.isfinite(dist)
    cls = np.where(valid, tri_class[np.clip(prim, 0, len(tri_class) - 1)], -1)
    ok = ((cls == wall) & (dist > 0.6) & (dist < 3.0)).reshape(len(yaws), -1).mean(1) >= 0.8
    if not ok.any():
        return None
    best = int(np.argmin(np.where(ok, np.abs(yaws - yaw0), np.inf)))
    f = np.array([math.cos(pitch) * math.cos(yaws[best]), math.cos(pitch) * math.sin(yaws[best]), math.sin(pitch)])
    x = np.cross(f, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    return np.stack([x, np.cross(f, x), f], 1)


# --------------------------------------------------------------------------------------------------
# jitter
# --------------------------------------------------------------------------------------------------
def _add_jitter(poses: np.ndarray, rng: np.random.Generator, p: MotionParams) -> np.ndarray:
    """Nearly white shake in the camera frame, scaled to the target high-pass standard deviation per axis."""
    n = len(poses)
    envelope = np.exp(JITTER_BURSTS * _ou(rng, n, 10.0))[:, None]  # hands shake in bursts, not evenly
    trans = _shake(rng, n, p.jitter_sigma_frames[0], np.asarray(p.jitter_mm) / 1000.0, envelope)
    rot = _shake(rng, n, p.jitter_sigma_frames[1], np.radians(p.jitter_deg), envelope)
    out = poses.copy()
    out[:, :3, :3] = poses[:, :3, :3] @ Rotation.from_rotvec(rot).as_matrix()
    out[:, :3, 3] = poses[:, :3, 3] + np.einsum("nij,nj->ni", poses[:, :3, :3], trans)
    return out


def _shake(rng: np.random.Generator, n: int, sigma_frames: float, target: np.ndarray,
           envelope: np.ndarray) -> np.ndarray:
    """(n, 3) Gaussian noise times ``envelope``, smoothed over ``sigma_frames``, with high-pass std ``target``."""
    x = rng.standard_normal((n, 3)) * envelope
    if sigma_frames > 0:
        x = gaussian_filter1d(x, sigma_frames, axis=0, mode="nearest")
    hp = x - gaussian_filter1d(x, JITTER_HP_FRAMES, axis=0, mode="nearest")
    return x * (target / np.maximum(hp.std(0), 1e-12))
