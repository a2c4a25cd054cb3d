"""The up direction in the camera frame: given (an accelerometer, a declared world frame and the pose) or
estimated from the depth itself, as Gupta et al. (CVPR 2013) do for HHA: start from a prior, then alternately
take the surfaces nearly parallel and nearly perpendicular to it and solve for the direction most parallel to the
first and most perpendicular to the second (an eigenvector), with tighter angles each round."""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

import numpy as np

from semmap.errors import ConfigError
from semmap.perception.structure.surface import Surface

#: A camera held upright and looking a little down (10°, as people hold one): image rows point down, so up is
#: near -y in the camera frame, tipped towards -z.
UPRIGHT = np.array([0.0, -np.cos(np.radians(10.0)), -np.sin(np.radians(10.0))])
#: Angles (degrees) of the rounds: a normal within this of the up direction is a floor/ceiling/table surface,
#: within this of the horizontal a wall.
ROUND_ANGLES = (45.0, 30.0, 20.0, 15.0, 8.0, 5.0)
#: Weight of the prior direction against the surfaces (a share of their total area): it decides only what the
#: surfaces leave open (a lone wall fixes up only to a circle of directions).
PRIOR_WEIGHT = 0.05
#: Normals the estimate uses at most (every k-th cell beyond): plenty for three directions, and 4x faster.
MAX_NORMALS = 4000
#: How much a start's score drops at 90° from the prior (a camera is seldom rolled or pointed straight down).
PRIOR_PREFERENCE = 0.2


class UpSource(str, Enum):
    """Where a frame's up direction came from, first found wins."""

    DATASET = "dataset"  #: the recording's accelerometer / IMU
    DECLARED = "declared"  #: --up: the world frame is gravity-aligned, carried into the frame by its pose
    MAP = "map"  #: estimated from earlier frames of the sequence, carried by the poses
    DEPTH = "depth"  #: estimated from this frame's depth alone


@dataclass(frozen=True)
class UpEstimate:
    """A unit up vector in the camera frame, where it came from, and the share of the surface area that agrees
    with it (lying within 15° of horizontal or vertical)."""

    up: np.ndarray
    source: UpSource
    support: float


def unit(v: np.ndarray, what: str = "up direction") -> np.ndarray:
    """``v`` scaled to length 1 (ConfigError for a zero or non-finite vector)."""
    v = np.asarray(v, np.float64).reshape(3)
    n = float(np.linalg.norm(v))
    if not np.isfinite(n) or n < 1e-9:
        raise ConfigError(f"{what} {v.tolist()} is not a direction")
    return v / n


def estimate_up(surface: Surface, prior: np.ndarray = UPRIGHT) -> UpEstimate:
    """The up direction that makes the most surface area horizontal or vertical, near ``prior`` (camera frame).

    Refined from several starts (the prior and the three principal directions of the normals, so a view down at
    the floor or along a rolled camera starts near the truth), the best by its support, with a mild preference
    for directions near the prior where the surfaces leave a choice (a lone wall fixes up only to a circle)."""
    ok = surface.has_normal
    n = surface.normals[ok][:: max(1, int(ok.sum()) // MAX_NORMALS)]  # an even thinning: the same directions
    w = surface.area[ok][:: max(1, int(ok.sum()) // MAX_NORMALS)]
    prior = unit(prior)
    if len(n) < 3 or w.sum() <= 0:
        return UpEstimate(prior, UpSource.DEPTH, 0.0)
    _, axes = np.linalg.eigh((n * w[:, None]).T @ n)
    best: tuple[float, np.ndarray, float] | None = None
    for start in (prior, *axes.T):
        start = start if start @ prior >= 0 else -start
        up = _refine(n, w, start)
        support = _support(n, w, up)
        angle = np.degrees(np.arccos(np.clip(up @ prior, -1.0, 1.0)))
        score = support * (1.0 - PRIOR_PREFERENCE * min(angle / 90.0, 1.0) ** 2)
        if best is None or score > best[0]:
            best = (score, up, support)
    return UpEstimate(best[1], UpSource.DEPTH, best[2])


def _refine(n: np.ndarray, w: np.ndarray, start: np.ndarray) -> np.ndarray:
    """Gupta et al.'s rounds from ``start``: the eigenvector most parallel to the aligned normals and most
    perpendicular to the others, a little of the round's own start added for what they leave open."""
    up = start
    total = float(w.sum())
    for angle in ROUND_ANGLES:
        c = np.abs(n @ up)
        sign = (c > np.cos(np.radians(angle))).astype(np.float64) - (c < np.sin(np.radians(angle)))
        m = (n * (w * sign)[:, None]).T @ n + PRIOR_WEIGHT * total * np.outer(up, up)
        vals, vecs = np.linalg.eigh(m)
        new = vecs[:, int(np.argmax(vals))]
        up = new if new @ up >= 0 else -new
    return up


def _support(n: np.ndarray, w: np.ndarray, up: np.ndarray) -> float:
    """Share of the surface area within 15° of horizontal or vertical for ``up``."""
    c = np.abs(n @ up)
    agree = (c > np.cos(np.radians(15.0))) | (c < np.sin(np.radians(15.0)))
    return float(w[agree].sum() / w.sum())


def up_in_camera(up_world: np.ndarray, T_world_cam: np.ndarray) -> np.ndarray:
    """A world-frame up direction seen from a camera with pose ``T_world_cam`` (camera to world)."""
    return np.asarray(T_world_cam, np.float64)[:3, :3].T @ up_world


def up_in_world(up_cam: np.ndarray, T_world_cam: np.ndarray) -> np.ndarray:
    """A camera-frame up direction in the world frame."""
    return np.asarray(T_world_cam, np.float64)[:3, :3] @ up_cam


#: ``--up`` values: the world axis that points up.
AXES = {"+x": (1.0, 0.0, 0.0), "-x": (-1.0, 0.0, 0.0), "+y": (0.0, 1.0, 0.0), "-y": (0.0, -1.0, 0.0),
        "+z": (0.0, 0.0, 1.0), "-z": (0.0, 0.0, -1.0)}


def parse_up(text: str) -> np.ndarray:
    """``--up``: an axis (``+z``, ``-y``, ...) or three numbers ``x,y,z``, as a unit world vector."""
    key = str(text).strip().lower()
    if key in AXES:
        return np.array(AXES[key])
    if key in {"x", "y", "z"}:
        return np.array(AXES["+" + key])
    try:
        values = [float(p) for p in key.split(",")]
    except ValueError:
        values = []
    if len(values) != 3:
        raise ConfigError(f"--up {text!r}: give the world axis that points up ({', '.join(AXES)}) or three "
                          f"numbers x,y,z")
    return unit(np.array(values), f"--up {text!r}")
