"""TUM-format trajectory files (``timestamp tx ty tz qx qy qz qw``) as :class:`semmap.types.Trajectory`.

The one TUM reader (tolerant with warnings, or strict: every problem a :class:`FormatError` naming the file and
line) and pose interpolation between its rows; writing is atomic.
Also the rotation clean-up that real ground truth needs: slightly non-orthonormal rotations (7-Scenes is off by
up to 3e-4, which ``evo`` rejects) are snapped to the nearest rotation, far-off ones are an error.
"""

from __future__ import annotations

import logging
import re
from pathlib import Path

import numpy as np

from semmap.errors import FormatError
from semmap.files.atomic import write_text_atomic
from semmap.files.parse import is_number
from semmap.files.safe import read_text_limited
from semmap.limits import LIMITS
from semmap.types import Trajectory, interpolate_pose, pose_from_tum, pose_to_tum, poses_from_tum

LOG = logging.getLogger("semmap")

#: Largest accepted deviation | ‖q‖ − 1 | of a stored quaternion (it is normalised on reading).
QUAT_NORM_TOL = 0.1
#: Largest accepted max |R Rᵀ − I| before a rotation is re-orthonormalised instead of rejected.
ORTHO_TOL = 1e-2
HEADER = "# timestamp tx ty tz qx qy qz qw"
#: Farthest camera position (m from the origin) a trajectory row may hold (the limits table's ``position``).
FAR = LIMITS["position"].hi


def read_tum(path: str | Path, *, strict: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Timestamps (N,) and rows ``tx ty tz qx qy qz qw`` (N, 7) of a TUM trajectory file, sorted by time.

    Tolerant by default: a row with non-finite pose values is kept as NaN (no pose is interpolated next to it) and
    rows out of order or sharing a timestamp are sorted, each with a warning. ``strict``: those are errors, as are
    a quaternion norm off by more than :data:`QUAT_NORM_TOL` and a file without rows. A malformed row is always a
    :class:`FormatError` naming the file and line."""
    path = Path(path)
    text = read_text_limited(path, what="trajectory file")
    stamps: list[float] = []
    rows: list[np.ndarray] = []
    bad: list[int] = []
    for number, line in enumerate(text.splitlines(), start=1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        stamp, values = _parse_row(path, number, line, strict=strict)
        if strict and stamps and stamp <= stamps[-1]:
            raise FormatError(f"{path}:{number}: timestamp {stamp!r} is not after the previous one "
                              f"({stamps[-1]!r}); timestamps must increase strictly")
        if not np.isfinite(values).all():
            bad.append(number)
        stamps.append(stamp)
        rows.append(values)
    if strict and not rows:
        raise FormatError(f"{path}: no poses (expected rows 'timestamp tx ty tz qx qy qz qw')")
    if bad:
        LOG.warning("%s: %d poses have non-finite entries or positions beyond ±%g m (lines %s); frames at their "
                    "times are skipped", path, len(bad), FAR,
                    ", ".join(map(str, bad[:5])) + (" ..." if len(bad) > 5 else ""))
    times = np.asarray(stamps, dtype=np.float64)
    warn_repeated_stamps(path, times)
    order = np.argsort(times, kind="stable")
    return times[order], np.asarray(rows, dtype=np.float64).reshape(-1, 7)[order]


def read_trajectory(path: str | Path, *, strict: bool = False) -> Trajectory:
    """Poses of a TUM trajectory file (:func:`read_tum`); tolerant reading leaves out rows without a finite pose
    and all but the first row of a repeated timestamp."""
    stamps, rows = read_tum(path, strict=strict)
    finite = np.isfinite(rows).all(axis=1)
    stamps, rows = stamps[finite], rows[finite]
    if not len(rows):
        raise FormatError(f"{path}: no poses (expected rows 'timestamp tx ty tz qx qy qz qw')")
    first = np.concatenate([[True], stamps[1:] != stamps[:-1]])
    return Trajectory(stamps[first], poses_from_tum(rows[first]))


def _parse_row(path: Path, number: int, line: str, *, strict: bool) -> tuple[float, np.ndarray]:
    """(timestamp, ``tx ty tz qx qy qz qw``) of one data row (NaN values where the pose is not finite, unless
    ``strict``), or :class:`FormatError` naming ``path:number``."""
    fields = re.split(r"[\s,]+", line)
    if len(fields) != 8:
        raise FormatError(f"{path}:{number}: expected 8 values (timestamp tx ty tz qx qy qz qw), "
                          f"got {len(fields)}")
    bad = next((v for v in fields if not is_number(v)), None)
    if bad is not None:
        raise FormatError(f"{path}:{number}: {bad!r} is not a number")
    values = np.array([float(v) for v in fields], dtype=np.float64)
    if not np.isfinite(values[0]):
        raise FormatError(f"{path}:{number}: timestamp {fields[0]!r} is not finite")
    pose = values[1:]
    if not np.isfinite(pose).all() or np.abs(pose[:3]).max() > FAR:
        if strict:
            raise FormatError(f"{path}:{number}: pose has non-finite entries or a position beyond ±{FAR:g} m")
        return float(values[0]), np.full(7, np.nan)
    norm = float(np.linalg.norm(pose[3:]))
    if norm < 1e-9:
        raise FormatError(f"{path}:{number}: quaternion is zero")
    if strict and abs(norm - 1.0) > QUAT_NORM_TOL:
        raise FormatError(f"{path}:{number}: quaternion norm is {norm:.4f}, expected 1 "
                          f"(columns must be tx ty tz qx qy qz qw)")
    return float(values[0]), pose


def warn_repeated_stamps(path: Path, stamps) -> None:
    """Warn when rows of a TUM file share a timestamp (only one of them can be paired or looked up)."""
    times = np.asarray(stamps, dtype=np.float64)
    repeated = len(times) - len(np.unique(times))
    if repeated:
        LOG.warning("%s: %d rows repeat an earlier timestamp; at most one row per timestamp is used", path, repeated)


def pose_at(stamps: np.ndarray, rows: np.ndarray, t: float, max_time_diff: float) -> np.ndarray | None:
    """``T_world_cam`` at time ``t`` from :func:`read_tum`'s rows: interpolated between the bracketing rows (linear
    translation, slerp rotation), clamped to an end row within ``max_time_diff`` of the trajectory's time range,
    None further outside, next to a non-finite row, or with no trajectory."""
    if len(stamps) == 0 or t < stamps[0] - max_time_diff or t > stamps[-1] + max_time_diff:
        return None
    if t <= stamps[0]:
        return _finite_pose(rows[0])
    if t >= stamps[-1]:
        return _finite_pose(rows[-1])
    j = int(np.searchsorted(stamps, t, side="right"))  # stamps[j - 1] <= t < stamps[j]
    i = j - 1
    if stamps[i] == t:
        return _finite_pose(rows[i])
    if not (np.isfinite(rows[i]).all() and np.isfinite(rows[j]).all()):
        return None
    alpha = (t - stamps[i]) / (stamps[j] - stamps[i])
    return interpolate_pose(pose_from_tum(rows[i]), pose_from_tum(rows[j]), alpha)


def _finite_pose(row: np.ndarray) -> np.ndarray | None:
    return pose_from_tum(row) if np.isfinite(row).all() else None


def format_trajectory(trajectory: Trajectory) -> str:
    """TUM text of a trajectory: a header comment, then one ``timestamp tx ty tz qx qy qz qw`` row per pose."""
    rows = [HEADER]
    for stamp, T in zip(trajectory.timestamps, trajectory.poses, strict=True):
        values = " ".join(f"{v:.9g}" for v in pose_to_tum(T))
        rows.append(f"{stamp:.9f} {values}")
    return "\n".join(rows) + "\n"


def write_trajectory(path: str | Path, trajectory: Trajectory) -> Path:
    """Write ``trajectory`` as a TUM file, atomically (a failed write leaves an older file untouched)."""
    return write_text_atomic(path, format_trajectory(trajectory))


# --------------------------------------------------------------------------------------------------
# Rotations
# --------------------------------------------------------------------------------------------------
def clean_poses(poses: np.ndarray, source: str, tol: float = ORTHO_TOL) -> np.ndarray:
    """Copy of (N, 4, 4) poses with every rotation re-orthonormalised; :class:`FormatError` naming ``source``
    and the pose index when a rotation is further than ``tol`` from orthonormal or a reflection, or a pose is
    non-finite or not rigid (last row not 0 0 0 1). Vectorised: a million poses take a second, not a minute."""
    poses = np.array(poses, dtype=np.float64).reshape(-1, 4, 4)
    if len(poses) == 0:
        return poses
    bad = np.flatnonzero(~np.isfinite(poses).all(axis=(1, 2)))
    if len(bad):
        raise FormatError(f"{source}: pose {int(bad[0])} has non-finite entries")
    bottom = np.array([0.0, 0.0, 0.0, 1.0])
    bad = np.flatnonzero(~np.isclose(poses[:, 3], bottom, rtol=1e-5, atol=1e-9).all(axis=1))
    if len(bad):
        i = int(bad[0])
        raise FormatError(f"{source}: pose {i} is not a rigid transform (last row {poses[i, 3].tolist()})")
    R = poses[:, :3, :3]
    err = np.abs(R @ np.swapaxes(R, 1, 2) - np.eye(3)).max(axis=(1, 2))
    bad = np.flatnonzero((err > tol) | (np.linalg.det(R) <= 0))
    if len(bad):
        i = int(bad[0])
        raise FormatError(f"{source}: pose {i} has a rotation that is not orthonormal "
                          f"(max |R Rᵀ - I| = {err[i]:.2g}, tolerance {tol:g}) or is a reflection")
    U, _, Vt = np.linalg.svd(R)  # the nearest proper rotation of each (see semmap.types.orthonormalize)
    sign = np.sign(np.linalg.det(U @ Vt))
    U[:, :, 2] *= sign[:, None]
    poses[:, :3, :3] = U @ Vt
    poses[:, 3] = bottom
    return poses


def clean_trajectory(trajectory: Trajectory, source: str, tol: float = ORTHO_TOL) -> Trajectory:
    """``trajectory`` with re-orthonormalised rotations (see :func:`clean_poses`)."""
    return Trajectory(trajectory.timestamps, clean_poses(trajectory.poses, source, tol), trajectory.names)
