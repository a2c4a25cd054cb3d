"""Colour like a real camera: what a hand-held RGB-D camera's colour sensor does to the ideal rendered image.

The renderer's colour is a perfect pinhole image taken at the depth frame's instant. A :class:`ColourParams`
turns it into what a Kinect-class colour camera records (all channels are off in preset ``"clean"``, whose output
is the renderer's image, unchanged):

- **motion blur**: the image integrates over the exposure while the camera moves. Each pixel's image motion
  (px/s) follows from its depth and the camera's velocity (the motion field of a rigid scene,
  ``dX/dt = -v - w x X``); the pixel averages the ideal image along that motion over ``exposure_s``;
- **rolling shutter**: row ``r`` is exposed ``readout_s * (r / (H - 1) - 0.5)`` seconds after the frame's middle
  row, i.e. it is shifted by the same image motion times that delay;
- **colour-depth time offset** (colour taken ``time_offset_s`` after depth: a shift by motion x offset) and
  **misregistration** (a constant pixel offset ``offset_px`` between the colour and depth images);
- **auto-exposure** (partial compensation of the frame's mean brightness) and **exposure / white-balance
  drift** (slow mean-reverting random walks of the overall and per-channel gains, reproducible per frame);
- **vignetting** (natural ``cos^4``-like fall-off, ``vignetting`` = darkening at the corners);
- **sensor noise**: shot noise (variance proportional to the signal) plus read noise, in 8-bit units;
- **JPEG compression** (``cv2.imencode`` at ``jpeg_quality``, 4:2:0 like the 7-Scenes colour files).

A Gaussian **lens blur** (``lens_blur_px``: optics, demosaicing and the sensor's downscaling soften a Kinect's
colour image; 7-Scenes' frames are far less sharp than an ideal render) is applied first. One numba kernel then
does the geometric part, gains, vignetting and noise in a single pass over the image (a counter-based hash picks
each value's noise from a table of normal numbers, so threads share no generator); JPEG is one ``cv2`` encode
and decode. Random numbers come from ``(seed, frame_index)``, so every frame is reproducible on its own.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import cv2
import numba as nb
import numpy as np

from semmap.errors import SimulationError

#: Stream ids mixed into the per-frame seeds (never shared with depth noise or trajectories).
_NOISE_STREAM = 0xC0102
_DRIFT_STREAM = 0xC0103
#: Steps of the gain random walks generated per block (blocks are seeded separately: any frame is reachable).
_DRIFT_BLOCK = 256
#: Most samples one pixel averages along its motion during the exposure.
MAX_BLUR_SAMPLES = 24
#: Depth assumed where the ray hits nothing (metres), for the image motion there.
FAR_DEPTH_M = 5.0
#: Mean brightness (8-bit) auto-exposure steers towards.
AE_TARGET = 118.0
PRESETS: tuple[str, ...] = ("clean", "kinect", "hard")
#: 65536 standard-normal numbers (fixed stream) that the noise of each pixel and channel is picked from.
_NORMALS = np.random.default_rng(_NOISE_STREAM).standard_normal(65536).astype(np.float32)


@dataclass(frozen=True)
class ColourParams:
    """What the colour camera does to the ideal image; every default is off (the renderer's image unchanged)."""

    exposure_s: float = 0.0  # exposure time (motion blur); 0 = instantaneous
    lens_blur_px: float = 0.0  # Gaussian sigma of the optics' blur (pixels)
    readout_s: float = 0.0  # rolling-shutter readout, first to last row; 0 = global shutter
    time_offset_s: float = 0.0  # colour captured this long after the depth image
    offset_px: tuple[float, float] = (0.0, 0.0)  # colour-depth misregistration (x, y) in pixels
    vignetting: float = 0.0  # relative darkening in the image corners (0..0.9)
    auto_exposure: float = 0.0  # share of a frame's brightness error auto-exposure removes (0..1)
    exposure_drift: float = 0.0  # std of the log overall gain's slow random walk
    white_balance_drift: float = 0.0  # std of the log red and blue gains' slow random walks
    drift_time_s: float = 8.0  # correlation time of the drifts (seconds)
    shot_noise: float = 0.0  # noise variance per 8-bit unit of signal
    read_noise: float = 0.0  # signal-independent noise std (8-bit units)
    jpeg_quality: int = 0  # JPEG quality 1..100; 0 = no compression
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("exposure_s", "lens_blur_px", "readout_s", "shot_noise", "read_noise", "exposure_drift",
                     "white_balance_drift"):
            value = getattr(self, name)
            if not (math.isfinite(value) and 0.0 <= value <= 10.0):
                raise SimulationError(f"colour {name} must be in 0..10, got {value!r}")
        if not (math.isfinite(self.time_offset_s) and abs(self.time_offset_s) <= 1.0):
            raise SimulationError(f"colour time_offset_s must be within +-1 s, got {self.time_offset_s!r}")
        if len(self.offset_px) != 2 or not all(math.isfinite(v) and abs(v) <= 64 for v in self.offset_px):
            raise SimulationError(f"colour offset_px must be two numbers within +-64 px, got {self.offset_px!r}")
        if not 0.0 <= self.vignetting <= 0.9 or not 0.0 <= self.auto_exposure <= 1.0:
            raise SimulationError("colour vignetting must be in 0..0.9 and auto_exposure in 0..1")
        if not (isinstance(self.jpeg_quality, (int, np.integer)) and 0 <= self.jpeg_quality <= 100):
            raise SimulationError(f"colour jpeg_quality must be an integer 0..100, got {self.jpeg_quality!r}")
        if not self.drift_time_s > 0:
            raise SimulationError(f"colour drift_time_s must be positive, got {self.drift_time_s!r}")

    @property
    def is_clean(self) -> bool:
        """True when every channel is off (the renderer's image passes unchanged)."""
        return self.with_seed(0) == ColourParams()

    @property
    def moves(self) -> bool:
        """True when the image depends on the camera's motion (blur, rolling shutter, time offset)."""
        return self.exposure_s > 0 or self.readout_s > 0 or self.time_offset_s != 0

    def with_seed(self, seed: int) -> ColourParams:
        """The same camera with another random stream."""
        return replace(self, seed=int(seed))


#: The presets: ``kinect`` is a Kinect v1 colour camera as 7-Scenes recorded it (jpg quality 80 read from its
#: files' quantisation tables, 4:2:0; residual misregistration ~3 px after registration, see
#: ``datasets/sevenscenes.py``; lens blur and noise chosen so that the Laplacian variance, mean gradient and
#: noise estimate of simulated frames come near 7-Scenes', ``benchmarks/bench_realism_camera.py``); ``hard`` is
#: a worse camera in dimmer light (longer exposure, more noise, softer optics, stronger compression).
_PRESETS: dict[str, ColourParams] = {
    "clean": ColourParams(),
    "kinect": ColourParams(exposure_s=0.012, lens_blur_px=0.55, readout_s=0.025, time_offset_s=0.008,
                           offset_px=(1.5, 1.0), vignetting=0.25, auto_exposure=0.5, exposure_drift=0.06,
                           white_balance_drift=0.03, shot_noise=0.2, read_noise=1.2, jpeg_quality=80),
    "hard": ColourParams(exposure_s=0.025, lens_blur_px=0.8, readout_s=0.033, time_offset_s=0.017, offset_px=(3.0, 2.0),
                         vignetting=0.4, auto_exposure=0.7, exposure_drift=0.12, white_balance_drift=0.06,
                         shot_noise=0.6, read_noise=3.0, jpeg_quality=60),
}


def colour_params(preset: str, seed: int = 0) -> ColourParams:
    """The colour camera of ``preset`` (clean, kinect, hard) with random stream ``seed``."""
    if preset not in _PRESETS:
        raise SimulationError(f"unknown colour preset {preset!r}; choose one of {', '.join(PRESETS)}")
    return _PRESETS[preset].with_seed(seed)


def twist_between(T0: np.ndarray, T1: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Camera-frame linear (m/s) and angular (rad/s) velocity moving from pose ``T0`` to ``T1`` in ``dt`` s."""
    rel = np.linalg.solve(np.asarray(T0, np.float64), np.asarray(T1, np.float64))
    R = rel[:3, :3]
    cos = np.clip((np.trace(R) - 1.0) / 2.0, -1.0, 1.0)
    angle = math.acos(cos)
    axis = np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
    w = axis * (0.5 if angle < 1e-9 else angle / (2.0 * math.sin(angle)))
    return rel[:3, 3] / dt, w / dt


def sequence_twist(poses: np.ndarray, i: int, fps: float) -> tuple[np.ndarray, np.ndarray]:
    """Velocity of the camera at frame ``i`` of ``poses`` (central difference; one-sided at the ends)."""
    n = len(poses)
    if n < 2:
        return np.zeros(3), np.zeros(3)
    a, b = max(i - 1, 0), min(i + 1, n - 1)
    v, w = twist_between(poses[a], poses[b], (b - a) / fps)
    if a < i < b:  # central difference: express it in frame i's camera (a half step of rotation away)
        Ra = np.linalg.solve(poses[i][:3, :3], poses[a][:3, :3])
        v, w = Ra @ v, Ra @ w
    return v, w


def gains(params: ColourParams, frame_index: int, fps: float) -> np.ndarray:
    """Per-channel (r, g, b) gains of frame ``frame_index``: exposure drift times white-balance drift."""
    if params.exposure_drift == 0 and params.white_balance_drift == 0:
        return np.ones(3, np.float32)
    walk = _drift(params.seed, int(frame_index), math.exp(-1.0 / (params.drift_time_s * fps)))
    log_g = params.exposure_drift * walk[0] + params.white_balance_drift * np.array([walk[1], 0.0, walk[2]])
    return np.exp(log_g).astype(np.float32)


def _drift(seed: int, n: int, a: float) -> np.ndarray:
    """Value at step ``n`` of three unit-variance AR(1) walks with coefficient ``a`` (x_k = a x_(k-1) + ...)."""
    span = int(min(n, math.ceil(12.0 / max(1.0 - a, 1e-9))))  # older steps weigh less than a^span ~ 6e-6
    first = n - span
    blocks = range(first // _DRIFT_BLOCK, n // _DRIFT_BLOCK + 1)
    eps = np.concatenate([np.random.default_rng([_DRIFT_STREAM, int(seed), b]).standard_normal((_DRIFT_BLOCK, 3))
                          for b in blocks])
    start = blocks[0] * _DRIFT_BLOCK
    steps = eps[first - start:n - start + 1]  # steps first..n
    weights = a ** np.arange(len(steps) - 1, -1, -1, dtype=np.float64)
    return math.sqrt(1.0 - a * a) * (weights @ steps)


def apply_colour(rgb: np.ndarray, depth: np.ndarray, fx: float, fy: float, cx: float, cy: float,
                 params: ColourParams, frame_index: int, twist: tuple[np.ndarray, np.ndarray] | None = None,
                 fps: float = 30.0) -> np.ndarray:
    """``rgb`` (H, W, 3 uint8, the ideal image at the depth frame's instant) as the camera of ``params`` records
    it; ``depth`` (H, W metres, exact, 0 = nothing hit) and the camera-frame ``twist`` (v m/s, w rad/s) give
    each pixel's image motion. Clean parameters return ``rgb`` itself."""
    if params.is_clean:
        return rgb
    if rgb.shape != (*depth.shape, 3) or rgb.dtype != np.uint8 or min(depth.shape) < 2:
        raise SimulationError(f"colour image {rgb.shape} {rgb.dtype} does not match depth {depth.shape} "
                              f"(expected uint8 (H, W, 3), at least 2x2)")
    v, w = (np.zeros(3), np.zeros(3)) if twist is None else twist
    g = gains(params, frame_index, fps)
    if params.auto_exposure > 0:
        mean = float(rgb[::8, ::8].mean()) * float(g.mean())
        g = g * (AE_TARGET / max(mean, 1.0)) ** params.auto_exposure
    key = np.random.default_rng([_NOISE_STREAM, int(params.seed), int(frame_index)]).integers(
        0, 2**63, dtype=np.uint64)
    k = params.vignetting
    vig_a = (1.0 - k) ** -0.5 - 1.0 if k > 0 else 0.0
    out = np.empty_like(rgb)
    if params.lens_blur_px > 0:
        rgb = cv2.GaussianBlur(rgb, (0, 0), params.lens_blur_px)
    _camera_kernel(np.ascontiguousarray(rgb), np.ascontiguousarray(depth, np.float32), fx, fy, cx, cy,
                   np.asarray(v, np.float64), np.asarray(w, np.float64), params.time_offset_s, params.exposure_s,
                   params.readout_s, float(params.offset_px[0]), float(params.offset_px[1]), g.astype(np.float32),
                   vig_a, params.shot_noise, params.read_noise, np.uint64(key), _NORMALS, out)
    if params.jpeg_quality > 0:
        out = jpeg(out, params.jpeg_quality)
    return out


def jpeg(rgb: np.ndarray, quality: int) -> np.ndarray:
    """``rgb`` after a JPEG round trip at ``quality`` (4:2:0 chroma, as the camera's files)."""
    ok, buf = cv2.imencode(".jpg", rgb[:, :, ::-1], [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:  # pragma: no cover - cv2 encodes every uint8 image
        raise SimulationError("JPEG encoding of a rendered frame failed")
    return np.ascontiguousarray(cv2.imdecode(buf, cv2.IMREAD_COLOR)[:, :, ::-1])


@nb.njit(cache=True, inline="always", error_model="numpy")
def _hash(key, index):  # pragma: no cover - compiled
    """64 random bits for pixel ``index`` under ``key`` (splitmix64): counter-based, so threads share no generator
    and every frame is reproducible on its own."""
    x = key + np.uint64(index) * np.uint64(0x9E3779B97F4A7C15)
    x = (x ^ (x >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    x = (x ^ (x >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return x ^ (x >> np.uint64(31))


@nb.njit(cache=True, parallel=True, error_model="numpy", fastmath=True)
def _camera_kernel(rgb, depth, fx, fy, cx, cy, v, w, t_offset, exposure, readout, off_x, off_y, gain, vig_a,
                   shot, read, key, normals, out):  # pragma: no cover - compiled
    H, W = depth.shape
    corner2 = max(((W - 1 - cx) / fx) ** 2 + ((H - 1 - cy) / fy) ** 2, (cx / fx) ** 2 + (cy / fy) ** 2)
    noisy = shot > 0.0 or read > 0.0
    read2 = read * read
    m16 = np.uint64(0xFFFF)
    g0 = float(gain[0])
    g1 = float(gain[1])
    g2 = float(gain[2])
    v0, v1, v2 = v[0], v[1], v[2]
    w0, w1, w2 = w[0], w[1], w[2]
    ifx = 1.0 / fx
    for r in nb.prange(H):
        t_row = t_offset + (readout * (r / (H - 1.0) - 0.5) if H > 1 else 0.0)
        yn = (r - cy) / fy
        for u in range(W):
            xn = (u - cx) * ifx
            z = depth[r, u]
            iz = 1.0 / z if z > 0.0 else 0.2  # nothing hit: 5 m
            # motion field of a static point seen by a camera moving with (v, w): translation scales with 1/z
            du = fx * ((xn * v2 - v0) * iz + w0 * xn * yn - w1 * (1.0 + xn * xn) + w2 * yn)
            dv = fy * ((yn * v2 - v1) * iz + w0 * (1.0 + yn * yn) - w1 * xn * yn - w2 * xn)
            # the colour pixel at time t shows what the ideal image holds at (u, r) - motion * t
            bx = u + off_x - du * t_row
            by = r + off_y - dv * t_row
            n = min(int(math.sqrt(du * du + dv * dv) * exposure) + 1, 24)
            step = exposure / n
            s0 = 0.5 * step - 0.5 * exposure
            a0 = 0.0
            a1 = 0.0
            a2 = 0.0
            for k in range(n):
                s = s0 + k * step
                x = min(max(bx - du * s, 0.0), W - 1.0)
                y = min(max(by - dv * s, 0.0), H - 1.0)
                x0 = min(int(x), W - 2)
                y0 = min(int(y), H - 2)
                ax = x - x0
                ay = y - y0
                w00 = (1.0 - ax) * (1.0 - ay)
                w01 = ax * (1.0 - ay)
                w10 = (1.0 - ax) * ay
                w11 = ax * ay
                a0 += w00 * rgb[y0, x0, 0] + w01 * rgb[y0, x0 + 1, 0] + w10 * rgb[y0 + 1, x0, 0] \
                    + w11 * rgb[y0 + 1, x0 + 1, 0]
                a1 += w00 * rgb[y0, x0, 1] + w01 * rgb[y0, x0 + 1, 1] + w10 * rgb[y0 + 1, x0, 1] \
                    + w11 * rgb[y0 + 1, x0 + 1, 1]
                a2 += w00 * rgb[y0, x0, 2] + w01 * rgb[y0, x0 + 1, 2] + w10 * rgb[y0 + 1, x0, 2] \
                    + w11 * rgb[y0 + 1, x0 + 1, 2]
            rad2 = (xn * xn + yn * yn) / corner2
            vig = 1.0 + vig_a * rad2
            scale = 1.0 / (n * vig * vig)
            a0 *= scale * g0
            a1 *= scale * g1
            a2 *= scale * g2
            if noisy:  # three 16-bit indices of one hash pick standard-normal numbers from the table
                h = _hash(key, r * W + u)
                a0 += math.sqrt(shot * max(a0, 0.0) + read2) * normals[h & m16]
                a1 += math.sqrt(shot * max(a1, 0.0) + read2) * normals[(h >> np.uint64(16)) & m16]
                a2 += math.sqrt(shot * max(a2, 0.0) + read2) * normals[(h >> np.uint64(32)) & m16]
            out[r, u, 0] = int(min(max(a0 + 0.5, 0.0), 255.0))
            out[r, u, 1] = int(min(max(a1 + 0.5, 0.0), 255.0))
            out[r, u, 2] = int(min(max(a2 + 0.5, 0.0), 255.0))
