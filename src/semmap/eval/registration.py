"""How well colour lines up with depth: the mean distance from depth outlines (the near side of a depth jump) to
the nearest colour edge. Registered RGB-D images score a few pixels (edges in colour and depth never coincide
everywhere); colour from a second camera used as if it were the depth camera scores more."""

from __future__ import annotations

import cv2
import numpy as np

#: a pixel whose neighbour is this much farther is on the near side of a depth discontinuity
JUMP_RATIO = 1.08
#: pixels; distances to colour edges are capped here so that outlines without a colour edge weigh little
MAX_DISTANCE = 8.0


def depth_outlines(depth: np.ndarray, border: int = 3) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(u, v, z) of depth pixels on the near side of a depth discontinuity (``border`` pixels left out)."""
    z = np.where(depth > 0, depth, np.nan)
    near = np.zeros(z.shape, bool)
    for dy, dx in ((0, 1), (0, -1), (1, 0), (-1, 0)):
        other = np.roll(np.roll(z, dy, 0), dx, 1)
        with np.errstate(invalid="ignore"):
            near |= other > z * JUMP_RATIO
    near[:border], near[-border:], near[:, :border], near[:, -border:] = False, False, False, False
    v, u = np.nonzero(near)
    return u.astype(np.float64), v.astype(np.float64), z[v, u].astype(np.float64)


def edge_distance(rgb: np.ndarray) -> np.ndarray:
    """Distance (pixels, capped at ``MAX_DISTANCE``) from every colour pixel to the nearest Canny edge."""
    gray = cv2.GaussianBlur(cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY), (5, 5), 1.2)
    edges = cv2.Canny(gray, 40, 100)
    return np.minimum(cv2.distanceTransform((edges == 0).astype(np.uint8), cv2.DIST_L2, 3), MAX_DISTANCE)


def sample(image: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Bilinear samples of a float image at (x, y) (inside the image)."""
    return cv2.remap(image, x.astype(np.float32)[:, None], y.astype(np.float32)[:, None], cv2.INTER_LINEAR)[:, 0]


def edge_misalignment(rgb: np.ndarray, depth: np.ndarray) -> float:
    """Mean distance (pixels) from the depth outlines of a frame to the colour edges at the same pixels."""
    u, v, _ = depth_outlines(depth)
    if len(u) == 0:
        return float("nan")
    return float(sample(edge_distance(rgb), u, v).mean())
