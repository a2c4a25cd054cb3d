"""numba kernels of the renderer: ray generation and per-pixel shading (texture, Lambert, ids, depth).

Each pixel is computed independently, so the parallel loops give identical results in any thread order;
fastmath stays off so vectorised and scalar iterations round alike (same bytes for any thread count).
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

#: open3d's id for "no hit".
INVALID_ID = np.uint32(0xFFFFFFFF)


@nb.njit(cache=True, parallel=True)
def make_rays(dirs_cam, R, origin, out):  # pragma: no cover - compiled
    """Fill (N, 6) float32 rays [origin, R @ dir] for camera-frame directions (N, 3)."""
    n = dirs_cam.shape[0]
    for i in nb.prange(n):
        dx, dy, dz = dirs_cam[i, 0], dirs_cam[i, 1], dirs_cam[i, 2]
        out[i, 0] = origin[0]
        out[i, 1] = origin[1]
        out[i, 2] = origin[2]
        out[i, 3] = R[0, 0] * dx + R[0, 1] * dy + R[0, 2] * dz
        out[i, 4] = R[1, 0] * dx + R[1, 1] * dy + R[1, 2] * dz
        out[i, 5] = R[2, 0] * dx + R[2, 1] * dy + R[2, 2] * dz


@nb.njit(cache=True, inline="always")
def _texel(data, base, size, x, y, c):  # pragma: no cover - compiled
    return np.float32(data[base + (y * size + x) * 3 + c])


@nb.njit(cache=True, parallel=True)
def shade(tri_ids, z_hit, dirs_cam, R, origin, tri_normal, tri_uvmap, tri_density, tri_mat, tri_class, tri_inst,
          mat_tex, mat_scale, mat_emissive, tex_data, tex_off, tex_size, tex_levels,
          lights, light_power, ambient, headlight, falloff2, inv_f,
          rgb, depth, labels, instances, cos_out):  # pragma: no cover - compiled
    """Shade every pixel from its visible triangle id (-1: none) and depth along the optical axis."""
    n = tri_ids.shape[0]
    n_lights = lights.shape[0]
    for i in nb.prange(n):
        tri = tri_ids[i]
        if tri < 0:
            rgb[i, 0] = 0
            rgb[i, 1] = 0
            rgb[i, 2] = 0
            depth[i] = 0.0
            labels[i] = 0
            instances[i] = 0
            cos_out[i] = 0.0
            continue
        z = z_hit[i]
        cx_, cy_ = dirs_cam[i, 0], dirs_cam[i, 1]
        dx = R[0, 0] * cx_ + R[0, 1] * cy_ + R[0, 2]
        dy = R[1, 0] * cx_ + R[1, 1] * cy_ + R[1, 2]
        dz = R[2, 0] * cx_ + R[2, 1] * cy_ + R[2, 2]
        dlen = math.sqrt(dx * dx + dy * dy + dz * dz)
        nx, ny, nz = tri_normal[tri, 0], tri_normal[tri, 1], tri_normal[tri, 2]
        dn = nx * dx + ny * dy + nz * dz
        if dn > 0.0:  # face the camera
            nx, ny, nz, dn = -nx, -ny, -nz, -dn
        cos_i = -dn / dlen
        px = origin[0] + z * dx
        py = origin[1] + z * dy
        pz = origin[2] + z * dz

        # texture coordinates (affine map of the triangle's plane) and mip level from the pixel footprint
        u = tri_uvmap[tri, 0] * px + tri_uvmap[tri, 1] * py + tri_uvmap[tri, 2] * pz + tri_uvmap[tri, 3]
        v = tri_uvmap[tri, 4] * px + tri_uvmap[tri, 5] * py + tri_uvmap[tri, 6] * pz + tri_uvmap[tri, 7]
        m = tri_mat[tri]
        tex = mat_tex[m]
        scale = mat_scale[m]
        footprint = z * dlen * inv_f / max(cos_i, 0.25) * tri_density[tri]
        lvl = 0
        top = tex_levels[tex] - 1
        while footprint >= 2.0 and lvl < top:
            footprint *= 0.5
            lvl += 1
        size = tex_size[tex] >> lvl
        mask = size - 1
        base = tex_off[tex, lvl]
        inv = 1.0 / (1 << lvl)
        x = u * scale * inv - 0.5
        y = v * scale * inv - 0.5
        xf = math.floor(x)
        yf = math.floor(y)
        ax = x - xf
        ay = y - yf
        x0 = int(xf) & mask
        y0 = int(yf) & mask
        x1 = (x0 + 1) & mask
        y1 = (y0 + 1) & mask

        # Lambert shading from point lights with soft distance falloff, plus ambient and a weak headlight
        light = ambient + headlight * cos_i
        for k in range(n_lights):
            lx = lights[k, 0] - px
            ly = lights[k, 1] - py
            lz = lights[k, 2] - pz
            d2 = lx * lx + ly * ly + lz * lz
            ndl = (nx * lx + ny * ly + nz * lz) / math.sqrt(d2)
            if ndl > 0.0:
                light += light_power * ndl / (1.0 + d2 / falloff2)
        e = mat_emissive[m]
        gain = light * (1.0 - e) + e * 1.1
        w00 = (1.0 - ax) * (1.0 - ay)
        w10 = ax * (1.0 - ay)
        w01 = (1.0 - ax) * ay
        w11 = ax * ay
        for c in range(3):
            a = _texel(tex_data, base, size, x0, y0, c) * w00 + _texel(tex_data, base, size, x1, y0, c) * w10 \
                + _texel(tex_data, base, size, x0, y1, c) * w01 + _texel(tex_data, base, size, x1, y1, c) * w11
            rgb[i, c] = np.uint8(min(255.0, max(0.0, a * gain + 0.5)))
        depth[i] = z
        labels[i] = tri_class[tri]
        instances[i] = tri_inst[tri]
        cos_out[i] = cos_i
