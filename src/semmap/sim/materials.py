"""Surface materials: which procedural texture a triangle shows, how large one tile is, how it is lit."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from semmap.errors import SimulationError

#: Texture patterns :mod:`semmap.sim.textures` knows how to draw.
PATTERNS: frozenset[str] = frozenset({
    "paint", "wood", "planks", "tiles", "ceiling_tiles", "fabric", "carpet", "leather", "plastic", "metal",
    "screen", "poster", "book", "keycap", "foliage", "soil", "skin", "sky", "cardboard", "whiteboard",
    "granite", "porcelain",
})

#: Patterns whose UVs span the unit square of one object face (the texture is fitted, not tiled).
FITTED_PATTERNS: frozenset[str] = frozenset({"screen", "poster", "sky", "whiteboard", "keycap"})

RGB = tuple[int, int, int]


@dataclass(frozen=True)
class Material:
    """A procedural texture (``pattern`` in two colours, seeded) tiled every ``tile_m`` metres of UV.

    ``emissive`` in [0, 1] adds self-illumination (window views, screens) on top of the Lambert shading.
    """

    pattern: str
    color: RGB
    color2: RGB = (0, 0, 0)
    tile_m: float = 1.0
    seed: int = 0
    size: int = 256
    emissive: float = 0.0

    def __post_init__(self) -> None:
        if self.pattern not in PATTERNS:
            raise SimulationError(f"unknown texture pattern {self.pattern!r}; known: {', '.join(sorted(PATTERNS))}")
        if not self.tile_m > 0:
            raise SimulationError(f"material tile size must be positive, got {self.tile_m}")
        if self.size < 4 or self.size & (self.size - 1):
            raise SimulationError(f"texture size must be a power of two >= 4, got {self.size}")

    @property
    def key(self) -> tuple:
        """Identity of the texture image (materials with equal keys share one texture)."""
        return (self.pattern, self.color, self.color2, self.seed, self.size)


def jitter_color(rng: np.random.Generator, color: RGB, amount: float = 0.12) -> RGB:
    """``color`` with each channel scaled by a random factor in [1 - amount, 1 + amount], clipped, never white."""
    c = np.asarray(color, float) * rng.uniform(1 - amount, 1 + amount, 3)
    return _rgb(c)


def pick(rng: np.random.Generator, palette: list[RGB] | tuple[RGB, ...]) -> RGB:
    """One colour of ``palette``, chosen by ``rng``."""
    return palette[int(rng.integers(len(palette)))]


def _rgb(c: np.ndarray) -> RGB:
    c = np.clip(np.rint(c), 0, 250).astype(int)
    return int(c[0]), int(c[1]), int(c[2])


#: Palettes the object builders draw from (RGB albedo, 0..255).
WOODS: tuple[RGB, ...] = ((150, 105, 65), (186, 140, 95), (110, 72, 45), (205, 170, 120), (90, 60, 40))
FABRICS: tuple[RGB, ...] = ((70, 90, 130), (120, 60, 60), (80, 110, 80), (150, 140, 120), (60, 60, 70),
                            (170, 120, 70), (110, 90, 140))
PAINTS: tuple[RGB, ...] = ((225, 220, 205), (210, 215, 220), (200, 210, 190), (230, 210, 190), (215, 205, 225))
METALS: tuple[RGB, ...] = ((160, 165, 170), (90, 95, 100), (40, 40, 45), (200, 200, 205))
PLASTICS: tuple[RGB, ...] = ((35, 35, 38), (200, 200, 195), (60, 60, 65), (180, 40, 40), (40, 80, 160))
BRIGHTS: tuple[RGB, ...] = ((200, 40, 40), (40, 120, 200), (230, 180, 40), (40, 160, 90), (150, 60, 170),
                            (230, 120, 40), (30, 30, 30), (220, 220, 210), (120, 70, 40), (60, 170, 180))
