"""Procedural, tileable texture images (wood grain, fabric, tiles, posters, book spines, ...) for materials.

Every image is drawn once per scene from the material's seed with numpy only, so textures are deterministic
and cost nothing per frame. Noise is made periodic (filtered white noise via FFT) so tiles join seamlessly.
"""

from __future__ import annotations

import numpy as np

from semmap.sim.materials import Material

#: Smallest mip level kept (texels per side).
MIN_MIP_SIZE = 2


def make_texture(material: Material) -> np.ndarray:
    """(S, S, 3) uint8 albedo image of ``material`` (S = ``material.size``)."""
    rng = np.random.default_rng([material.seed, _pattern_code(material.pattern)])
    size = material.size
    c1 = np.asarray(material.color, np.float32)
    c2 = np.asarray(material.color2, np.float32)
    img = _DRAW[material.pattern](rng, size, c1, c2)
    return np.clip(np.rint(img), 0, 250).astype(np.uint8)


def mip_chain(image: np.ndarray) -> list[np.ndarray]:
    """Box-filtered mip levels of a square power-of-two ``image``, level 0 first, down to MIN_MIP_SIZE."""
    levels = [image]
    while levels[-1].shape[0] > MIN_MIP_SIZE:
        a = levels[-1].astype(np.float32)
        half = (a[0::2, 0::2] + a[1::2, 0::2] + a[0::2, 1::2] + a[1::2, 1::2]) * 0.25
        levels.append(np.rint(half).astype(np.uint8))
    return levels


# --------------------------------------------------------------------------------------------------
# building blocks
# --------------------------------------------------------------------------------------------------
def _pattern_code(name: str) -> int:
    """Stable integer for a pattern name (no hash(): that is salted per process)."""
    return sum((i + 1) * ord(ch) for i, ch in enumerate(name))


def _noise(rng: np.random.Generator, size: int, scale: float, aspect: float = 1.0) -> np.ndarray:
    """Periodic smooth noise (size, size), zero mean, unit std; ``scale`` = feature size in texels.

    ``aspect`` > 1 stretches features along x (wood grain).
    """
    white = rng.standard_normal((size, size))
    f = np.fft.fftfreq(size)
    fy, fx = np.meshgrid(f, f, indexing="ij")
    r2 = (fx * scale / aspect) ** 2 + (fy * scale) ** 2
    field = np.real(np.fft.ifft2(np.fft.fft2(white) * np.exp(-r2 * 4.0)))
    std = field.std()
    return (field / std if std > 0 else field).astype(np.float32)


def _shade(color: np.ndarray, factor: np.ndarray) -> np.ndarray:
    """Colour image (S, S, 3) = ``color`` scaled per texel by ``factor`` (S, S)."""
    return color[None, None, :] * factor[..., None]


def _mix(a: np.ndarray, b: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Per-texel blend of two colours (or images) by ``t`` (S, S) in [0, 1]."""
    t = np.clip(t, 0.0, 1.0)[..., None]
    a = a if a.ndim == 3 else a[None, None, :]
    b = b if b.ndim == 3 else b[None, None, :]
    return a * (1 - t) + b * t


def _fill(img: np.ndarray, y0: int, y1: int, x0: int, x1: int, color: np.ndarray) -> None:
    """Paint an axis-aligned rectangle (clipped to the image)."""
    s = img.shape[0]
    img[max(y0, 0):min(y1, s), max(x0, 0):min(x1, s)] = color


def _text(img: np.ndarray, rng: np.random.Generator, box: tuple[int, int, int, int], ink: np.ndarray,
          line_h: int, vertical: bool = False) -> None:
    """Text-like marks inside ``box`` (y0, y1, x0, x1): lines of word-sized blocks with letter gaps."""
    y0, y1, x0, x1 = box
    if vertical:  # draw into a rotated view so "lines" run along y
        view = np.swapaxes(img, 0, 1)
        _text(view, rng, (x0, x1, y0, y1), ink, line_h)
        return
    glyph_h = max(1, int(line_h * 0.6))
    y = y0
    while y + glyph_h <= y1:
        x = x0 + int(rng.integers(0, max(1, line_h)))
        end = x1 - int(rng.integers(0, max(1, (x1 - x0) // 3)))
        while x < end:
            word = int(rng.integers(2, 8))
            for _ in range(word):
                w = int(rng.integers(max(1, glyph_h // 3), max(2, glyph_h)))
                if x + w > end:
                    break
                top = y + (0 if rng.random() < 0.7 else int(rng.integers(0, max(1, glyph_h // 3))))
                _fill(img, top, y + glyph_h, x, x + w, ink)
                x += w + max(1, glyph_h // 4)
            x += max(2, glyph_h)
        y += line_h


# --------------------------------------------------------------------------------------------------
# patterns
# --------------------------------------------------------------------------------------------------
def _paint(rng, s, c1, c2):
    f = 1.0 + 0.025 * _noise(rng, s, s / 4) + 0.03 * _noise(rng, s, 2.0)
    return _shade(c1, f)


def _wood(rng, s, c1, c2):
    """Wood grain: thin darker growth lines running along u, gently wavy, with fine streaks."""
    rings = int(rng.integers(10, 20))
    y = np.arange(s, dtype=np.float32)[:, None] / s
    warp = 0.25 * _noise(rng, s, s / 6, aspect=8.0) / rings * 3.0
    t = 0.5 + 0.5 * np.cos(2 * np.pi * rings * (y + warp))
    streaks = _noise(rng, s, 1.0, aspect=16.0)
    dark = c2 if c2.any() else c1 * 0.7
    img = _mix(c1, dark, 0.65 * t ** 8 + 0.12 * streaks + 0.12)
    return img * (1.0 + 0.04 * _noise(rng, s, s / 5, aspect=3.0))[..., None]


def _planks(rng, s, c1, c2):
    n_rows = 4
    img = np.empty((s, s, 3), np.float32)
    row_h = s // n_rows
    for r in range(n_rows):
        tone = 1.0 + rng.uniform(-0.12, 0.12)
        grain = _wood(rng, s, c1 * tone, c1 * tone * 0.72)
        shift = int(rng.integers(0, s))
        img[r * row_h:(r + 1) * row_h] = np.roll(grain[r * row_h:(r + 1) * row_h], shift, axis=1)
        img[r * row_h:r * row_h + 2] *= 0.55  # seam between planks
        img[r * row_h:(r + 1) * row_h, shift % s:(shift % s) + 2] *= 0.6  # butt joint
    return img


def _tiles(rng, s, c1, c2, n: int = 2, grout: int = 3):
    img = np.empty((s, s, 3), np.float32)
    step = s // n
    for i in range(n):
        for j in range(n):
            tone = 1.0 + rng.uniform(-0.07, 0.07)
            img[i * step:(i + 1) * step, j * step:(j + 1) * step] = c1 * tone
    img *= (1.0 + 0.05 * _noise(rng, s, 4.0) + 0.04 * _noise(rng, s, 1.0))[..., None]
    g = c2 if c2.any() else c1 * 0.6
    for k in range(n):
        img[k * step:k * step + grout] = g
        img[:, k * step:k * step + grout] = g
    return img


def _ceiling_tiles(rng, s, c1, c2):
    img = _tiles(rng, s, c1, c1 * 0.75, n=2, grout=2)
    speck = rng.random((s, s)) < 0.04
    img[speck] *= 0.85
    return img


def _fabric(rng, s, c1, c2):
    yy, xx = np.mgrid[0:s, 0:s]
    weave = np.where(((xx // 2) + (yy // 2)) % 2 == 0, 1.06, 0.94).astype(np.float32)
    f = weave * (1.0 + 0.06 * _noise(rng, s, s / 8) + 0.05 * _noise(rng, s, 1.2))
    img = _shade(c1, f)
    if c2.any():  # woven stripes or checks
        period = int(rng.choice([16, 32, 64]))
        band = ((yy % period) < period // 4) | ((xx % period) < period // 4) if rng.random() < 0.5 \
            else ((yy % period) < period // 3)
        img = np.where(band[..., None], _shade(c2, f), img)
    return img


def _carpet(rng, s, c1, c2):
    return _shade(c1, 1.0 + 0.09 * _noise(rng, s, 1.0) + 0.07 * _noise(rng, s, s / 6))


def _leather(rng, s, c1, c2):
    return _shade(c1, 1.0 + 0.05 * _noise(rng, s, 2.5) + 0.08 * _noise(rng, s, s / 5))


def _plastic(rng, s, c1, c2):
    return _shade(c1, 1.0 + 0.025 * _noise(rng, s, s / 4) + 0.02 * _noise(rng, s, 1.0))


def _metal(rng, s, c1, c2):
    brushed = _noise(rng, s, 1.0, aspect=30.0)
    return _shade(c1, 1.0 + 0.05 * brushed + 0.03 * _noise(rng, s, s / 3))


def _granite(rng, s, c1, c2):
    img = _shade(c1, 1.0 + 0.06 * _noise(rng, s, 6.0))
    dots = rng.random((s, s))
    dark = c2 if c2.any() else c1 * 0.4
    img[dots < 0.08] = dark
    img[dots > 0.96] = np.minimum(c1 * 1.3, 245)
    return img


def _porcelain(rng, s, c1, c2):
    return _shade(c1, 1.0 + 0.015 * _noise(rng, s, s / 4))


def _soil(rng, s, c1, c2):
    img = _shade(c1, 1.0 + 0.2 * _noise(rng, s, 1.5))
    img[rng.random((s, s)) < 0.05] *= 0.5
    return img


def _skin(rng, s, c1, c2):
    return _shade(c1, 1.0 + 0.03 * _noise(rng, s, s / 6))


def _foliage(rng, s, c1, c2):
    base = _noise(rng, s, 5.0)
    veins = _noise(rng, s, 1.5)
    light = c2 if c2.any() else np.minimum(c1 * 1.6, 240)
    img = _mix(c1 * 0.55, light, 0.5 + 0.35 * base + 0.15 * veins)
    img[base < -1.0] *= 0.45  # gaps between leaves look dark
    return img


def _cardboard(rng, s, c1, c2):
    img = _shade(c1, 1.0 + 0.06 * _noise(rng, s, 2.0) + 0.05 * _noise(rng, s, s / 4))
    tape = c2 if c2.any() else c1 * 1.15
    w = s // 10
    img[:, s // 2 - w // 2:s // 2 + w // 2] = tape
    _text(img, rng, (s // 8, s // 4, s // 10, s // 2 - w), np.array([40, 35, 30], np.float32), max(4, s // 24))
    return img


def _book(rng, s, c1, c2):
    """Book spine/cover: coloured with bands near the ends and a title along the spine."""
    img = _shade(c1, 1.0 + 0.04 * _noise(rng, s, 2.0))
    ink = c2 if c2.any() else (np.array([235, 225, 200], np.float32) if c1.mean() < 120
                               else np.array([25, 25, 30], np.float32))
    for y in (int(s * rng.uniform(0.05, 0.12)), int(s * rng.uniform(0.82, 0.9))):
        _fill(img, y, y + max(1, s // 40), 0, s, ink)
    _text(img, rng, (int(s * 0.2), int(s * 0.75), 0, s), ink, max(3, s // 12), vertical=False)
    return img


def _keycap(rng, s, c1, c2):
    img = _shade(c1, 1.0 + 0.02 * _noise(rng, s, 2.0))
    ink = c2 if c2.any() else np.array([225, 225, 225], np.float32)
    m = s // 4
    glyph = rng.random((3, 3)) < 0.55
    cell = (s - 2 * m) // 3
    for i in range(3):
        for j in range(3):
            if glyph[i, j]:
                _fill(img, m + i * cell, m + (i + 1) * cell - 1, m + j * cell, m + (j + 1) * cell - 1, ink)
    img[:2] *= 0.8
    img[:, :2] *= 0.8
    img[-2:] *= 0.8
    img[:, -2:] *= 0.8
    return img


def _poster(rng, s, c1, c2):
    """Picture/poster: a background, a few coloured shapes, a title and text-like lines."""
    img = _shade(c1, 1.0 + 0.03 * _noise(rng, s, s / 3))
    yy, xx = np.mgrid[0:s, 0:s].astype(np.float32)
    palette = np.array([[200, 40, 40], [40, 110, 200], [235, 190, 40], [40, 150, 80], [140, 60, 160],
                        [30, 30, 35], [240, 140, 60], [90, 200, 210]], np.float32)
    for _ in range(int(rng.integers(3, 8))):
        col = palette[int(rng.integers(len(palette)))]
        cx, cy = rng.uniform(0.1, 0.9, 2) * s
        r = rng.uniform(0.06, 0.25) * s
        if rng.random() < 0.5:
            mask = (xx - cx) ** 2 + (yy - cy) ** 2 < r * r
        else:
            mask = (np.abs(xx - cx) < r) & (np.abs(yy - cy) < r * rng.uniform(0.3, 1.0))
        img[mask] = col * rng.uniform(0.85, 1.1)
    ink = c2 if c2.any() else np.array([25, 25, 30], np.float32)
    _text(img, rng, (int(s * 0.05), int(s * 0.16), int(s * 0.08), int(s * 0.9)), ink, max(6, s // 10))
    _text(img, rng, (int(s * 0.7), int(s * 0.95), int(s * 0.08), int(s * 0.92)), ink, max(4, s // 28))
    return img


def _screen(rng, s, c1, c2):
    """Monitor/TV content: dark desktop, a few windows with title bars and text."""
    img = _shade(c1 if c1.any() else np.array([20, 30, 60], np.float32), 1.0 + 0.05 * _noise(rng, s, s / 2))
    for _ in range(int(rng.integers(2, 5))):
        y0, x0 = (rng.uniform(0.05, 0.55, 2) * s).astype(int)
        h, w = (rng.uniform(0.25, 0.45, 2) * s).astype(int)
        _fill(img, y0, y0 + h, x0, x0 + w, np.array([235, 235, 230], np.float32) * rng.uniform(0.8, 1.0))
        _fill(img, y0, y0 + max(3, s // 30), x0, x0 + w, np.array([60, 90, 170], np.float32))
        _text(img, rng, (y0 + s // 20, y0 + h - 2, x0 + 3, x0 + w - 3), np.array([30, 30, 40], np.float32),
              max(4, s // 32))
    _fill(img, s - max(4, s // 20), s, 0, s, np.array([40, 40, 50], np.float32))
    return img


def _sky(rng, s, c1, c2):
    """The view out of a window: sky gradient with clouds above a skyline of buildings and trees."""
    y = np.linspace(0, 1, s, dtype=np.float32)[:, None]
    top, bottom = np.array([90, 140, 210], np.float32), np.array([190, 210, 235], np.float32)
    img = np.broadcast_to(top * (1 - y[..., None]) + bottom * y[..., None], (s, s, 3)).copy()
    clouds = _noise(rng, s, s / 10, aspect=2.5)
    img = _mix(img, np.array([240, 240, 242], np.float32), np.clip(clouds - 0.6, 0, 1) * 1.5)
    x = 0
    while x < s:
        w = int(rng.integers(s // 12, s // 5))
        h = int(rng.uniform(0.2, 0.55) * s)
        col = np.array([120, 115, 110], np.float32) * rng.uniform(0.6, 1.2)
        _fill(img, s - h, s, x, x + w, col)
        for wy in range(s - h + 4, s - 4, 8):  # lit windows in the buildings
            for wx in range(x + 3, x + w - 4, 7):
                if rng.random() < 0.6:
                    _fill(img, wy, wy + 4, wx, wx + 3, np.array([60, 70, 90], np.float32))
        x += w + int(rng.integers(0, s // 16))
    trees = _noise(rng, s, 6.0)
    tree_line = s - (0.12 + 0.06 * trees[0]) * s
    mask = np.arange(s)[:, None] > tree_line[None, :]
    img[mask] = _mix(np.array([40, 90, 40], np.float32), np.array([80, 140, 60], np.float32),
                     0.5 + 0.4 * trees)[mask]
    return img


def _whiteboard(rng, s, c1, c2):
    img = _shade(c1, 1.0 + 0.01 * _noise(rng, s, s / 2))
    for _ in range(int(rng.integers(2, 5))):
        ink = np.array([[30, 60, 170], [20, 20, 25], [180, 30, 30], [30, 130, 50]][int(rng.integers(4))],
                       np.float32)
        y0, x0 = (rng.uniform(0.05, 0.6, 2) * s).astype(int)
        _text(img, rng, (y0, y0 + int(s * rng.uniform(0.15, 0.35)), x0, x0 + int(s * rng.uniform(0.2, 0.4))),
              ink, max(5, s // 20))
    return img


_DRAW = {
    "paint": _paint, "wood": _wood, "planks": _planks, "tiles": _tiles, "ceiling_tiles": _ceiling_tiles,
    "fabric": _fabric, "carpet": _carpet, "leather": _leather, "plastic": _plastic, "metal": _metal,
    "screen": _screen, "poster": _poster, "book": _book, "keycap": _keycap, "foliage": _foliage,
    "soil": _soil, "skin": _skin, "sky": _sky, "cardboard": _cardboard, "whiteboard": _whiteboard,
    "granite": _granite, "porcelain": _porcelain,
}


class TextureAtlas:
    """All textures of a scene with their mip levels in one flat uint8 buffer (for the numba shader).

    ``offsets[t, l]`` is the start of level ``l`` of texture ``t`` in ``data``, ``sizes[t]`` the level-0
    side length, ``levels[t]`` the number of levels; ``material_texture[m]`` the texture of material m.
    """

    def __init__(self, materials: list[Material]) -> None:
        index: dict[tuple, int] = {}
        chains: list[list[np.ndarray]] = []
        self.material_texture = np.zeros(len(materials), np.int32)
        for m, mat in enumerate(materials):
            if mat.key not in index:
                index[mat.key] = len(chains)
                chains.append(mip_chain(make_texture(mat)))
            self.material_texture[m] = index[mat.key]
        max_levels = max((len(c) for c in chains), default=1)
        self.offsets = np.zeros((len(chains), max_levels), np.int64)
        self.sizes = np.array([c[0].shape[0] for c in chains], np.int32)
        self.levels = np.array([len(c) for c in chains], np.int32)
        pos = 0
        for t, chain in enumerate(chains):
            for lvl, img in enumerate(chain):
                self.offsets[t, lvl] = pos
                pos += img.size
        self.data = np.empty(max(pos, 3), np.uint8)
        for t, chain in enumerate(chains):
            for lvl, img in enumerate(chain):
                self.data[self.offsets[t, lvl]:self.offsets[t, lvl] + img.size] = img.ravel()

    @property
    def n_textures(self) -> int:
        return len(self.sizes)
