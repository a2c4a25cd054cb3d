"""Kinect-v1-like depth noise: axial Gaussian noise, disparity quantisation and the typical missing data.

Model (applied to the exact ray-cast depth, seeded per frame so every frame is reproducible on its own):

- axial noise ``sigma(z) = 0.0012 + 0.0019 (z - 0.4)^2`` metres (Nguyen, Izadi, Lovell 2012);
- quantisation to the disparity steps of a structured-light sensor with ``focal_px`` = 575 px, baseline
  7.5 cm and 1/8-pixel sub-pixel disparity: ``d = f b / z`` rounded to 1/8 px, ``z = f b / d``;
- missing depth closer than ``min_depth`` (0.4 m), beyond ``max_depth`` (4.5 m), at grazing incidence
  (dropout probability rising linearly over ``grazing_deg`` +- ``grazing_ramp_deg`` / 2), and at depth
  discontinuities (the far side loses a band ``shadow_px`` wide, the near side a single pixel, randomly).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba as nb
import numpy as np

from semmap.errors import SimulationError

#: Stream id mixed into the per-frame seed so depth noise never shares random numbers with other users.
_NOISE_STREAM = 0x5EED


@dataclass(frozen=True)
class KinectNoise:
    """Parameters of the depth noise model; ``apply`` adds it to one frame's exact depth."""

    seed: int = 0
    min_depth: float = 0.4
    max_depth: float = 4.5
    focal_px: float = 575.0
    baseline_m: float = 0.075
    subpixel: float = 8.0
    sigma0: float = 0.0012
    sigma2: float = 0.0019
    grazing_deg: float = 75.0
    grazing_ramp_deg: float = 10.0
    edge_jump_rel: float = 0.05
    edge_far_p: float = 0.8
    edge_near_p: float = 0.3
    shadow_px: int = 2

    def __post_init__(self) -> None:
        if not 0 < self.min_depth < self.max_depth:
            raise SimulationError(f"depth range must satisfy 0 < min < max, got {self.min_depth}..{self.max_depth}")
        if self.focal_px <= 0 or self.baseline_m <= 0 or self.subpixel <= 0:
            raise SimulationError("focal length, baseline and sub-pixel factor must be positive")

    def sigma(self, z: np.ndarray | float) -> np.ndarray | float:
        """Axial standard deviation (metres) at depth ``z``."""
        return self.sigma0 + self.sigma2 * (np.asarray(z) - 0.4) ** 2

    def apply(self, depth: np.ndarray, cos_incidence: np.ndarray, frame_index: int) -> np.ndarray:
        """Noisy copy of ``depth`` (H, W float32 metres, 0 invalid); ``cos_incidence`` is |cos| of the angle
        between the viewing ray and the surface normal per pixel."""
        if depth.shape != cos_incidence.shape:
            raise SimulationError(f"depth {depth.shape} and incidence {cos_incidence.shape} differ in shape")
        rng = np.random.default_rng([_NOISE_STREAM, int(self.seed), int(frame_index)])
        gauss = rng.standard_normal(depth.shape, dtype=np.float32)
        uniform = rng.random(depth.shape, dtype=np.float32)
        out = np.empty_like(depth, dtype=np.float32)
        # dropout probability ramps linearly in cos(angle) between the two ends of the grazing band
        c0 = math.cos(math.radians(self.grazing_deg - self.grazing_ramp_deg / 2))
        c1 = math.cos(math.radians(self.grazing_deg + self.grazing_ramp_deg / 2))
        _noise_kernel(np.ascontiguousarray(depth, np.float32), np.ascontiguousarray(cos_incidence, np.float32),
                      gauss, uniform, out, self.min_depth, self.max_depth, self.focal_px * self.baseline_m,
                      self.subpixel, self.sigma0, self.sigma2, c0, c1, self.edge_jump_rel, self.edge_far_p,
                      self.edge_near_p, int(self.shadow_px))
        return out


@nb.njit(cache=True, inline="always")
def _jump(z, zn, rel):  # pragma: no cover - compiled
    """+1 if z lies beyond a discontinuity to zn, -1 if in front of one, 0 otherwise."""
    if zn <= 0.0:
        return 0
    if z - zn > rel * zn:
        return 1
    if zn - z > rel * z:
        return -1
    return 0


@nb.njit(cache=True, parallel=True)
def _noise_kernel(z_in, cos_in, gauss, uni, out, z_min, z_max, fb, subpx, s0, s2, c0, c1, jump_rel, p_far,
                  p_near, shadow):  # pragma: no cover - compiled
    H, W = z_in.shape
    for v in nb.prange(H):
        for u in range(W):
            z = z_in[v, u]
            out[v, u] = 0.0
            if z <= 0.0:
                continue
            r = uni[v, u]
            c = cos_in[v, u]
            if c <= c1 or (c < c0 and r < (c0 - c) / (c0 - c1)):
                continue  # grazing incidence
            far = False
            near = False
            for zn in (z_in[v, u - 1] if u > 0 else 0.0, z_in[v, u + 1] if u + 1 < W else 0.0,
                       z_in[v - 1, u] if v > 0 else 0.0, z_in[v + 1, u] if v + 1 < H else 0.0):
                j = _jump(z, zn, jump_rel)
                far |= j > 0
                near |= j < 0
            k = 2
            while not far and k <= shadow:
                far = (u >= k and _jump(z, z_in[v, u - k], jump_rel) > 0) or \
                      (u + k < W and _jump(z, z_in[v, u + k], jump_rel) > 0)
                k += 1
            if (far and r < p_far) or (near and r < p_near):
                continue  # depth discontinuity: shadow band behind, ragged edge in front
            zn = z + (s0 + s2 * (z - 0.4) * (z - 0.4)) * gauss[v, u]
            if zn <= 0.0:
                continue
            d = math.floor(fb / zn * subpx + 0.5) / subpx
            if d <= 0.0:
                continue
            zq = fb / d
            if z_min <= zq <= z_max:
                out[v, u] = zq
