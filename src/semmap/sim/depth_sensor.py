"""Depth sensors that look like real ones: a structured-light camera (Kinect v1) and a time-of-flight camera.

:class:`StructuredLight` turns the exact ray-cast depth into what a Kinect v1 reports:

- axial noise added in disparity, ``d = f b / z + sigma_d(theta) n``, so the depth error grows with ``z^2``
  (Khoshelham & Elberink 2012: ``sigma_z ~ 1.425e-3 z^2`` m is ``sigma_d ~ 0.06`` px at ``f b`` = 43.9 px m);
  ``sigma_d`` grows with the angle of incidence as in Nguyen, Izadi & Lovell 2012 (their ``theta^2 / (pi/2 -
  theta)^2`` term, computed as ``tan^2 theta``, which rises alike: 3 vs 4 at 60 deg, 32 vs 64 at 80 deg);
  part of it is spatially correlated (the sensor matches 9x9 windows of its speckle pattern), drawn on a coarse
  grid of ``corr_px`` pixels and interpolated bilinearly;
- disparity quantisation to ``1/subpixel`` px, ``z = f b / round(d)``: the terraces of a real Kinect;
- lateral noise at edges: each pixel reads its depth from a neighbour ``lateral_px`` (Gaussian) away when that
  neighbour lies across a depth discontinuity, so outlines are ragged; a pixel beside a discontinuity is lost
  with ``edge_drop_p``;
- holes where the projector's pattern is shadowed: the projector sits ``baseline_m`` beside the camera (at +x,
  as on a Kinect v1 seen from behind), so the background just beside a nearer object's edge on the side away from
  the projector is not lit; found by one sweep per row over the projector's image column ``u - f b / z``;
- holes on materials that return little infrared: dark albedo, specular (metal, screens, glazed porcelain) and
  transparent (window glass) surfaces drop pixels with per-material probabilities, in blobs of ``blob_px``;
- holes at grazing incidence, below ``min_depth`` and beyond ``max_depth`` (with a dropout ramp before it), and in
  the ``dead_px`` columns on the projector's side of the image, where the matching window does not fit;
- a low-frequency, spatially varying **disparity distortion** fixed for the unit (not per frame): the model of
  Herrera, Kannala & Heikkila 2012, ``d' = d + D(u, v) exp(-decay (fb / 1 m - d))``, with ``D`` a radial bowl
  (``distortion_px`` at the image corners, ``r^2``) plus a smooth per-unit field (``distortion_field_px``), so the
  depth error grows as ``z^2`` and towards the corners (Smisek et al. 2011; Teichman et al. 2013, CLAMS);
- the **true intrinsics** of the IR camera differ from the nominal ones a dataset publishes (``focal_error``,
  ``principal_offset_px``): :meth:`StructuredLight.sensor_intrinsics`, which the renderer looks through.

:class:`TimeOfFlight` is the optional alternative: noise growing linearly with depth (amplitude falls with the
incidence), no quantisation, flying pixels (depths between the two sides) at edges and multipath (corners seen
deeper than they are, by ``multipath_gain`` times the local concavity).

Random numbers come from a counter-based hash of (seed, frame, pixel), so every frame is reproducible on its own
and the parallel kernels give the same bytes for any thread count.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import cv2
import numba as nb
import numpy as np

from semmap.errors import SimulationError
from semmap.sim.materials import Material
from semmap.types import CameraIntrinsics

#: Stream id mixed into the per-frame key, so these numbers never coincide with another user's.
_STREAM = 0x5EED_D3A7
#: Material patterns with a specular (glossy) surface and with a transparent one (a window's pane).
SPECULAR_PATTERNS = frozenset({"metal", "screen", "porcelain"})
TRANSPARENT_PATTERNS = frozenset({"sky"})


@dataclass(frozen=True)
class StructuredLight:
    """Parameters of a Kinect-v1-like structured-light depth camera; :meth:`apply_view` renders one frame."""

    seed: int = 0
    min_depth: float = 0.8
    max_depth: float = 4.0
    far_drop_from: float = 3.5  # dropout ramps from 0 here to ``far_drop_p`` at max_depth
    far_drop_p: float = 0.2
    focal_px: float = 585.0  # the IR camera's focal length for the disparity (7-Scenes' Kinect)
    baseline_m: float = 0.075
    subpixel: float = 8.0
    sigma_disp_px: float = 0.052  # white disparity noise (px)
    sigma_corr_px: float = 0.037  # spatially correlated disparity noise (px)
    corr_px: int = 8
    angle_gain: float = 0.02  # sigma_d *= 1 + angle_gain * tan^2 theta
    grazing_deg: float = 86.0  # dropout ramps up over grazing_deg +- grazing_ramp_deg / 2
    grazing_ramp_deg: float = 6.0
    lateral_px: float = 0.6
    edge_jump_rel: float = 0.04
    edge_drop_p: float = 0.1
    shadow: bool = True
    projector_side: int = 1  # +1: projector at +x of the camera, -1: at -x
    shadow_slack_px: float = 5.0  # a pixel this little (px) inside the shadow still matches the pattern
    dark_luma: float = 45.0  # albedo luma (0..255) below which a material returns too little light
    dark_drop_p: float = 0.5
    specular_drop_p: float = 0.3
    transparent_drop_p: float = 0.95
    blob_px: int = 3
    dead_px: int = 8  # columns without depth on the projector's side of the image (7-Scenes: the last 8)
    distortion_px: float = 0.0  # disparity bias (px) at the image corners, growing as r^2 (+: reads nearer)
    distortion_field_px: float = 0.0  # std (px) of the unit's smooth non-radial disparity distortion field
    distortion_decay: float = 0.0  # Herrera's alpha_1 per px of disparity: the bias shrinks by exp(-decay) per px
    focal_error: float = 0.0  # relative error of the published focal length: true f = nominal f (1 + focal_error)
    principal_offset_px: tuple[float, float] = (0.0, 0.0)  # true principal point minus the published one (px)

    def __post_init__(self) -> None:
        if not 0 < self.min_depth < self.max_depth:
            raise SimulationError(f"depth range must satisfy 0 < min < max, got {self.min_depth}..{self.max_depth}")
        if self.focal_px <= 0 or self.baseline_m <= 0 or self.subpixel <= 0:
            raise SimulationError("focal length, baseline and sub-pixel factor must be positive")
        if self.corr_px < 1 or self.blob_px < 1 or self.projector_side not in (-1, 1):
            raise SimulationError("corr_px and blob_px must be >= 1 and projector_side -1 or +1")
        checks = (abs(self.distortion_px) <= 2.0, 0.0 <= self.distortion_field_px <= 2.0,
                  0.0 <= self.distortion_decay <= 10.0, abs(self.focal_error) <= 0.1,
                  len(self.principal_offset_px) == 2 and all(abs(o) <= 64 for o in self.principal_offset_px))
        if not all(checks):  # (NaN fails every comparison)
            raise SimulationError("depth distortion must be within +-2 px (field 0..2 px, decay 0..10), focal_error "
                                  "within +-0.1 and principal_offset_px two numbers within +-64 px")

    def sensor_intrinsics(self, published: CameraIntrinsics) -> CameraIntrinsics:
        """The IR camera's true intrinsics, given the nominal ones a dataset publishes (``published`` itself
        when both errors are zero, so exact frames stay exact)."""
        dx, dy = (float(o) for o in self.principal_offset_px)
        if self.focal_error == 0.0 and dx == 0.0 and dy == 0.0:
            return published
        g = 1.0 + float(self.focal_error)
        return CameraIntrinsics(published.width, published.height, published.fx * g, published.fy * g,
                                published.cx + dx, published.cy + dy)

    def distortion_image(self, height: int, width: int) -> np.ndarray:
        """The unit's disparity distortion ``D(u, v)`` (H, W float32, px, at 1 m; fixed per ``seed``, never per
        frame): ``distortion_px r^2`` (r = 1 at the corners) plus the smooth field."""
        return _distortion_image(float(self.distortion_px), float(self.distortion_field_px), int(self.seed),
                                 int(height), int(width))

    def disparity_bias(self, z: np.ndarray | float, u: np.ndarray | float, v: np.ndarray | float, height: int,
                       width: int) -> np.ndarray:
        """Disparity bias (px) of a pixel (u, v) seeing depth ``z`` (Herrera's ``D(u, v) exp(-decay (d_1m - d))``,
        d the true disparity ``fb / z``)."""
        D = self.distortion_image(height, width)
        d = self.focal_px * self.baseline_m / np.asarray(z, np.float64)
        dv = D[np.asarray(v, np.int64), np.asarray(u, np.int64)].astype(np.float64)
        return dv * np.exp(-self.distortion_decay * (self.focal_px * self.baseline_m - d))

    def depth_bias(self, z: np.ndarray | float, u: np.ndarray | float, v: np.ndarray | float, height: int,
                   width: int) -> np.ndarray:
        """Depth error (metres, negative: reads nearer) the distortion alone gives at (u, v) and true depth ``z``."""
        z = np.asarray(z, np.float64)
        fb = self.focal_px * self.baseline_m
        return fb / (fb / z + self.disparity_bias(z, u, v, height, width)) - z

    def axial_sigma(self, z: np.ndarray | float) -> np.ndarray | float:
        """Axial standard deviation (metres) at depth ``z`` seen head-on, before quantisation."""
        s = math.hypot(self.sigma_disp_px, self.sigma_corr_px)
        return np.asarray(z, np.float64) ** 2 * s / (self.focal_px * self.baseline_m)

    def quantum(self, z: np.ndarray | float) -> np.ndarray | float:
        """Depth step (metres) between two neighbouring disparities at depth ``z``."""
        return np.asarray(z, np.float64) ** 2 / (self.focal_px * self.baseline_m * self.subpixel)

    def material_dropout(self, materials: list[Material] | tuple[Material, ...]) -> np.ndarray:
        """Per-material probability (float32) that a pixel of it returns no depth: dark, specular, transparent."""
        out = np.zeros(len(materials), np.float32)
        for i, m in enumerate(materials):
            out[i] = material_drop(m, self.dark_luma, self.dark_drop_p, self.specular_drop_p,
                                   self.transparent_drop_p)
        return out

    def apply_view(self, depth: np.ndarray, cos_incidence: np.ndarray, frame_index: int, *, fx: float,
                   tri_ids: np.ndarray | None = None, tri_drop: np.ndarray | None = None) -> np.ndarray:
        """Sensor depth (H, W float32, 0 = none) from the exact ``depth``; ``cos_incidence`` is |cos| of the
        ray/normal angle, ``fx`` the image's focal length (pixels, for the shadows' width), ``tri_ids`` the
        visible triangle per pixel (-1 none) and ``tri_drop`` each triangle's material dropout probability."""
        z_in, cos_in = _checked(depth, cos_incidence)
        H, W = z_in.shape
        if tri_ids is None or tri_drop is None:
            tri_ids, tri_drop = np.full(H * W, -1, np.int32), np.zeros(1, np.float32)
        ids = np.ascontiguousarray(tri_ids, np.int32).reshape(H, W)
        key = _frame_key(self.seed, frame_index)
        grid = np.random.default_rng([_STREAM, int(self.seed), int(frame_index)]).standard_normal(
            (H // self.corr_px + 2, W // self.corr_px + 2)).astype(np.float32)
        shadow = np.zeros((H, W), np.uint8)
        if self.shadow:
            _shadow_kernel(z_in, float(fx) * self.baseline_m, int(self.projector_side), float(self.shadow_slack_px),
                           shadow)
        c0 = math.cos(math.radians(self.grazing_deg - self.grazing_ramp_deg / 2))
        c1 = math.cos(math.radians(self.grazing_deg + self.grazing_ramp_deg / 2))
        out = np.empty((H, W), np.float32)
        dist = self.distortion_image(H, W)
        _structured_kernel(z_in, cos_in, ids, np.ascontiguousarray(tri_drop, np.float32), shadow, grid, dist, key, out,
                           np.array([self.min_depth, self.max_depth, self.far_drop_from, self.far_drop_p,
                                     self.focal_px * self.baseline_m, self.subpixel, self.sigma_disp_px,
                                     self.sigma_corr_px, self.angle_gain, c0, c1, self.lateral_px,
                                     self.edge_jump_rel, self.edge_drop_p, self.distortion_decay], np.float64),
                           int(self.corr_px), int(self.blob_px), int(self.dead_px) * (self.projector_side > 0),
                           int(self.dead_px) * (self.projector_side < 0))
        return out


@dataclass(frozen=True)
class TimeOfFlight:
    """Parameters of a time-of-flight depth camera (Kinect v2 like); :meth:`apply_view` renders one frame."""

    seed: int = 0
    min_depth: float = 0.5
    max_depth: float = 4.5
    sigma0: float = 0.0015  # metres
    sigma1: float = 0.0015  # metres per metre of depth
    flying_p: float = 0.6  # probability that a pixel beside a discontinuity mixes the two depths
    edge_jump_rel: float = 0.04
    multipath_gain: float = 0.5
    multipath_px: int = 15
    dark_luma: float = 25.0
    dark_drop_p: float = 0.3
    specular_drop_p: float = 0.2
    transparent_drop_p: float = 0.95

    def __post_init__(self) -> None:
        if not 0 < self.min_depth < self.max_depth:
            raise SimulationError(f"depth range must satisfy 0 < min < max, got {self.min_depth}..{self.max_depth}")
        if self.multipath_px < 1 or self.multipath_px % 2 == 0:
            raise SimulationError(f"multipath_px must be a positive odd number, got {self.multipath_px}")

    def material_dropout(self, materials: list[Material] | tuple[Material, ...]) -> np.ndarray:
        """Per-material probability (float32) that a pixel of it returns no depth."""
        return np.array([material_drop(m, self.dark_luma, self.dark_drop_p, self.specular_drop_p,
                                       self.transparent_drop_p) for m in materials], np.float32).reshape(-1)

    def apply_view(self, depth: np.ndarray, cos_incidence: np.ndarray, frame_index: int, *, fx: float,
                   tri_ids: np.ndarray | None = None, tri_drop: np.ndarray | None = None) -> np.ndarray:
        """Sensor depth (H, W float32, 0 = none) from the exact ``depth`` (arguments as StructuredLight's)."""
        z, cos = _checked(depth, cos_incidence)
        valid = z > 0
        rng = np.random.default_rng([_STREAM + 1, int(self.seed), int(frame_index)])
        k = (self.multipath_px, self.multipath_px)
        weight = cv2.boxFilter(valid.astype(np.float32), -1, k, normalize=True)
        mean = cv2.boxFilter(z, -1, k, normalize=True) / np.maximum(weight, 1e-6)
        concave = z - mean  # > 0 where the neighbourhood is nearer: a corner seen from inside
        smooth = np.abs(concave) < 0.1 * np.maximum(z, 1e-6)
        out = z + np.where(valid & smooth, self.multipath_gain * np.maximum(concave, 0.0), 0.0).astype(np.float32)
        sigma = (self.sigma0 + self.sigma1 * z) / np.sqrt(np.maximum(cos, 0.05))
        out = out + sigma * rng.standard_normal(z.shape, dtype=np.float32)
        # flying pixels: beside a discontinuity, the return mixes the near and the far surface
        near, far = cv2.erode(np.where(valid, z, np.inf).astype(np.float32), None), cv2.dilate(z, None)
        edge = valid & (far - near > self.edge_jump_rel * near)
        t = rng.random(z.shape, dtype=np.float32)
        fly = edge & (rng.random(z.shape, dtype=np.float32) < self.flying_p)
        out = np.where(fly, near + t * (far - near), out)
        drop = np.zeros(z.shape, bool)
        if tri_ids is not None and tri_drop is not None and len(tri_drop):
            ids = np.asarray(tri_ids).reshape(z.shape)
            p = np.where(ids >= 0, tri_drop[np.clip(ids, 0, len(tri_drop) - 1)], 0.0)
            drop = rng.random(z.shape, dtype=np.float32) < p
        keep = valid & ~drop & (out >= self.min_depth) & (out <= self.max_depth)
        return np.where(keep, out, 0.0).astype(np.float32)


DepthSensor = StructuredLight | TimeOfFlight


def material_drop(m: Material, dark_luma: float, dark_p: float, specular_p: float, transparent_p: float) -> float:
    """Probability that a pixel of material ``m`` returns no depth: transparent, specular or dark (by albedo)."""
    if m.pattern in TRANSPARENT_PATTERNS:
        return transparent_p
    p = specular_p if m.pattern in SPECULAR_PATTERNS else 0.0
    luma = 0.5 * (_luma(m.color) + _luma(m.color2)) if m.color2 != (0, 0, 0) else _luma(m.color)
    if luma < dark_luma:
        p = max(p, dark_p * (1.0 - luma / dark_luma))
    return float(p)


def _luma(c: tuple[int, int, int]) -> float:
    return 0.299 * c[0] + 0.587 * c[1] + 0.114 * c[2]


def _checked(depth: np.ndarray, cos_incidence: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Contiguous float32 copies of the depth and incidence images, refused when their shapes differ."""
    if depth.ndim != 2 or depth.shape != cos_incidence.shape:
        raise SimulationError(f"depth {depth.shape} and incidence {cos_incidence.shape} must be one (H, W) shape")
    return np.ascontiguousarray(depth, np.float32), np.ascontiguousarray(cos_incidence, np.float32)


@functools.lru_cache(maxsize=8)
def _distortion_image(corner_px: float, field_px: float, seed: int, height: int, width: int) -> np.ndarray:
    """Disparity distortion image (px) of a unit: ``corner_px r^2`` plus a smooth field of std ``field_px`` drawn
    on a 4x5 grid of cells (rows x columns) and interpolated bicubically (the unit's own pattern, seeded by
    ``seed`` only)."""
    out = np.zeros((height, width), np.float32)
    if corner_px != 0.0:
        u = (np.arange(width, dtype=np.float64) - (width - 1) / 2) / ((width - 1) / 2)
        v = (np.arange(height, dtype=np.float64) - (height - 1) / 2) / ((height - 1) / 2)
        r2 = (u[None, :] ** 2 * width ** 2 + v[:, None] ** 2 * height ** 2) / (width ** 2 + height ** 2)
        out += (corner_px * r2).astype(np.float32)
    if field_px != 0.0:
        cells = np.random.default_rng([_STREAM + 2, seed]).standard_normal((4, 5)).astype(np.float32)
        field = cv2.resize(cells, (width, height), interpolation=cv2.INTER_CUBIC)
        out += field_px * field / max(float(field.std()), 1e-6)
    out.setflags(write=False)
    return out


def _frame_key(seed: int, frame_index: int) -> np.uint64:
    """64-bit key of one frame's random numbers."""
    h = np.random.default_rng([_STREAM, int(seed), int(frame_index)]).integers(0, 2**63, dtype=np.int64)
    return np.uint64(h)


@nb.njit(cache=True, inline="always")
def _mix(x):  # pragma: no cover - compiled
    """splitmix64 finaliser: a well-mixed 64-bit value from a counter."""
    x = (x ^ (x >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    x = (x ^ (x >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return x ^ (x >> np.uint64(31))


@nb.njit(cache=True, inline="always")
def _u16(h, k):  # pragma: no cover - compiled
    """The k-th 16-bit slice of ``h`` as a uniform number in [0, 1)."""
    return np.float64((h >> np.uint64(16 * k)) & np.uint64(0xFFFF)) * (1.0 / 65536.0)


@nb.njit(cache=True)
def _shadow_kernel(z, fb, side, slack, shadow):  # pragma: no cover - compiled
    """Mark pixels the projector (``side`` * baseline along x) cannot light: a sweep per row from the projector's
    side keeps the smallest projector column seen; a pixel whose column lies more than ``slack`` px beyond it is
    behind an occluder (within ``slack`` the matching window still sees enough of the pattern)."""
    H, W = z.shape
    for v in range(H):  # (serial: a few hundred microseconds, cheaper than a parallel region's start-up)
        best = 1e30
        for k in range(W):
            u = W - 1 - k if side > 0 else k
            d = z[v, u]
            p = side * u - fb / d if d > 0.0 else side * float(u)
            if d > 0.0 and p >= best + slack:
                shadow[v, u] = 1
            if p < best:
                best = p


@nb.njit(cache=True, inline="always")
def _is_jump(z, zn, rel):  # pragma: no cover - compiled
    """Whether ``zn`` lies across a depth discontinuity from ``z`` (or is missing)."""
    return zn <= 0.0 or abs(zn - z) > rel * min(z, zn)


@nb.njit(cache=True, parallel=True)
def _structured_kernel(z_in, cos_in, ids, tri_drop, shadow, grid, dist, key, out, prm, corr, blob, dead_right,
                       dead_left):  # pragma: no cover - compiled
    z_min, z_max, far0, far_p, fb, subpx = prm[0], prm[1], prm[2], prm[3], prm[4], prm[5]
    s_white, s_corr, a_gain, c0, c1, lat, rel, edge_p = (prm[6], prm[7], prm[8], prm[9], prm[10], prm[11],
                                                         prm[12], prm[13])
    decay = prm[14]
    H, W = z_in.shape
    lat_scale = lat * math.sqrt(6.0)
    for row in nb.prange(H):
        v = np.int64(row)
        for col in range(W):
            u = np.int64(col)
            out[v, u] = 0.0
            z = z_in[v, u]
            if z <= 0.0 or u >= W - dead_right or u < dead_left:
                continue  # nothing hit, or the correlation window does not fit at the image's side
            i = np.uint64(v * W + u)
            h1 = _mix(key + i * np.uint64(0x9E3779B97F4A7C15))
            edge = False
            for nu, nv in ((u - 1, v), (u + 1, v), (u, v - 1), (u, v + 1)):
                if 0 <= nu < W and 0 <= nv < H and _is_jump(z, z_in[nv, nu], rel):
                    edge = True
            su, sv = u, v
            if edge:
                # lateral noise: an edge pixel reads a neighbour's depth across the edge (ragged outlines)
                h2 = _mix(h1 ^ np.uint64(0xD1B54A32D192ED03))
                du = np.int64(math.floor(lat_scale * (_u16(h2, 0) + _u16(h2, 1) - 1.0) + 0.5))
                dv = np.int64(math.floor(lat_scale * (_u16(h2, 2) + _u16(h2, 3) - 1.0) + 0.5))
                nu, nv = min(max(u + du, 0), W - 1), min(max(v + dv, 0), H - 1)
                if _is_jump(z, z_in[nv, nu], rel):
                    su, sv = nu, nv
                    z = z_in[sv, su]
                    if z <= 0.0:
                        continue
            if shadow[sv, su]:
                continue
            if edge and _u16(h1, 0) < edge_p:
                continue
            # blobs: one draw per blob x blob cell (jittered per pixel), so the pattern is lost in patches, not salt
            jit = 0.2 * _u16(h1, 1)
            c = cos_in[sv, su]
            if c <= c1:
                continue  # grazing incidence
            t = ids[sv, su]
            p_gr = (c0 - c) / (c0 - c1) if c < c0 else 0.0
            p_mat = tri_drop[t] if t >= 0 else 0.0
            p_far = far_p * (z - far0) / max(z_max - far0, 1e-6) if z > far0 else 0.0
            if p_gr > 0.0 or p_mat > 0.0 or p_far > 0.0:
                hb = _mix(key ^ np.uint64((sv // blob) * 65536 + su // blob + 1) * np.uint64(0xA24BAED4963EE407))
                if (0.8 * _u16(hb, 0) + jit < p_gr or 0.8 * _u16(hb, 1) + jit < p_mat
                        or 0.8 * _u16(hb, 2) + jit < p_far):
                    continue  # grazing incidence, a dark, glossy or transparent material, the end of the range
            cc = max(c, 1e-3) * max(c, 1e-3)
            gain = 1.0 + a_gain * (1.0 - cc) / cc  # tan^2(theta), close to Nguyen's theta^2 / (pi/2 - theta)^2
            # correlated part: bilinear on the coarse grid of N(0, 1) values
            gx, gy = u / corr, v / corr
            ix, iy = int(gx), int(gy)
            fx_, fy_ = gx - ix, gy - iy
            g = ((1 - fx_) * (1 - fy_) * grid[iy, ix] + fx_ * (1 - fy_) * grid[iy, ix + 1]
                 + (1 - fx_) * fy_ * grid[iy + 1, ix] + fx_ * fy_ * grid[iy + 1, ix + 1])
            h3 = _mix(h1 ^ np.uint64(0x8CB92BA72F3D8DD7))
            n = (_u16(h3, 0) + _u16(h3, 1) + _u16(h3, 2) + _u16(h3, 3) - 2.0) * math.sqrt(3.0)
            d = fb / z + gain * (s_white * n + s_corr * g)
            bias = dist[v, u]
            if bias != 0.0:  # the unit's low-frequency distortion (Herrera et al. 2012)
                d += bias * math.exp(-decay * (fb - fb / z)) if decay > 0.0 else bias
            if d <= 0.0:
                continue
            d = math.floor(d * subpx + 0.5) / subpx
            if d <= 0.0:
                continue
            zq = fb / d
            if z_min <= zq <= z_max:
                out[v, u] = zq
