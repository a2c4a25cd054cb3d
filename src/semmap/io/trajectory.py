"""TUM-format trajectory files (``timestamp tx ty tz qx qy qz qw``) as :class:`semmap.types.Trajectory`.

Reading is strict (every problem is a :class:`FormatError` naming the file and line); writing is atomic.
Also the rotation clean-up that real ground truth needs: slightly non-orthonormal rotations (7-Scenes is off by
up to 3e-4, which ``evo`` rejects) are snapped to the nearest rotation, far-off ones are an error.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from semmap.errors import FormatError
from semmap.files.atomic import write_text_atomic
from semmap.types import Trajectory, orthonormalize, pose_from_tum, pose_to_tum

#: Largest accepted deviation | ‖q‖ − 1 | of a stored quaternion (it is normalised on reading).
QUAT_NORM_TOL = 0.1
#: Largest accepted max |R Rᵀ − I| before a rotation is re-orthonormalised instead of rejected.
ORTHO_TOL = 1e-2
HEADER = "# timestamp tx ty tz qx qy qz qw"


def read_trajectory(path: str | Path) -> Trajectory:
    """Poses of a TUM trajectory file, validated: :class:`FormatError` names the file and line of a bad row."""
    from semmap.files.safe import read_text_limited

    path = Path(path)
    text = read_text_limited(path, what="trajectory file")
    stamps: list[float] = []
    poses: list[np.ndarray] = []
    for number, line in enumerate(text.splitlines(), start=1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        stamp, pose = _parse_row(path, number, line)
        if stamps and stamp <= stamps[-1]:
            raise FormatError(f"{path}:{number}: timestamp {stamp!r} is not after the previous one "
                              f"({stamps[-1]!r}); timestamps must increase strictly")
        stamps.append(stamp)
        poses.append(pose)
    if not poses:
        raise FormatError(f"{path}: no poses (expected rows 'timestamp tx ty tz qx qy qz qw')")
    return Trajectory(np.asarray(stamps), np.stack(poses))


def _parse_row(path: Path, number: int, line: str) -> tuple[float, np.ndarray]:
    """(timestamp, 4x4 pose) of one data row, or :class:`FormatError` naming ``path:number``."""
    fields = re.split(r"[\s,]+", line)
    if len(fields) != 8:
        raise FormatError(f"{path}:{number}: expected 8 values (timestamp tx ty tz qx qy qz qw), "
                          f"got {len(fields)}")
    try:
        values = np.array([float(v) for v in fields], dtype=np.float64)
    except ValueError:
        bad = next(v for v in fields if not _is_float(v))
        raise FormatError(f"{path}:{number}: {bad!r} is not a number") from None
    if not np.isfinite(values).all():
        raise FormatError(f"{path}:{number}: row has non-finite values")
    norm = float(np.linalg.norm(values[4:]))
    if norm < 1e-9:
        raise FormatError(f"{path}:{number}: quaternion is zero")
    if abs(norm - 1.0) > QUAT_NORM_TOL:
        raise FormatError(f"{path}:{number}: quaternion norm is {norm:.4f}, expected 1 "
                          f"(columns must be tx ty tz qx qy qz qw)")
    return float(values[0]), pose_from_tum(values[1:])


def _is_float(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


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
def orthonormality_error(R: np.ndarray) -> float:
    """max |R Rᵀ − I| of a 3x3 matrix (0 for an exact rotation)."""
    R = np.asarray(R, dtype=np.float64)
    return float(np.abs(R @ R.T - np.eye(3)).max())


def clean_poses(poses: np.ndarray, source: str, tol: float = ORTHO_TOL) -> np.ndarray:
    """Copy of (N, 4, 4) poses with every rotation re-orthonormalised; :class:`FormatError` naming ``source``
    and the pose index when a rotation is further than ``tol`` from orthonormal or a reflection, or a pose is
    non-finite or not rigid (last row not 0 0 0 1)."""
    poses = np.array(poses, dtype=np.float64).reshape(-1, 4, 4)
    for i, T in enumerate(poses):
        if not np.isfinite(T).all():
            raise FormatError(f"{source}: pose {i} has non-finite entries")
        if not np.allclose(T[3], [0.0, 0.0, 0.0, 1.0], atol=1e-9):
            raise FormatError(f"{source}: pose {i} is not a rigid transform (last row {T[3].tolist()})")
        err = orthonormality_error(T[:3, :3])
        if err > tol or np.linalg.det(T[:3, :3]) <= 0:
            raise FormatError(f"{source}: pose {i} has a rotation that is not orthonormal "
                              f"(max |R Rᵀ - I| = {err:.2g}, tolerance {tol:g}) or is a reflection")
        poses[i, :3, :3] = orthonormalize(T[:3, :3])
        poses[i, 3] = (0.0, 0.0, 0.0, 1.0)
    return poses


def clean_trajectory(trajectory: Trajectory, source: str, tol: float = ORTHO_TOL) -> Trajectory:
    """``trajectory`` with re-orthonormalised rotations (see :func:`clean_poses`)."""
    return Trajectory(trajectory.timestamps, clean_poses(trajectory.poses, source, tol), trajectory.names)
