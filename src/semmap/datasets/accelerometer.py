"""Gravity from an accelerometer: at rest it reads the specific force, which points up; a frame's up direction is
the mean of the readings near its time, rotated into the camera frame (TUM's ``accelerometer.txt``, a ROS bag's
``sensor_msgs/Imu``)."""

from __future__ import annotations

import numpy as np

#: Readings this close in time (seconds) to a frame are averaged for its up direction (hand motion averages out).
ACCEL_WINDOW_S = 0.05
#: Readings whose magnitude is this far from 9.81 m/s² are the hand's acceleration, not gravity: left out.
ACCEL_TOLERANCE = 2.5


def up_at(stamps: np.ndarray, readings: np.ndarray, t: float) -> np.ndarray | None:
    """The unit up direction in the readings' frame at time ``t``: the mean of the readings within ACCEL_WINDOW_S
    whose magnitude is near gravity's, or None where there are none."""
    lo, hi = np.searchsorted(stamps, [t - ACCEL_WINDOW_S, t + ACCEL_WINDOW_S], side="left")
    near = readings[lo:hi]
    near = near[np.abs(np.linalg.norm(near, axis=1) - 9.81) < ACCEL_TOLERANCE]
    if len(near) == 0:
        return None
    mean = near.mean(axis=0)
    norm = float(np.linalg.norm(mean))
    return mean / norm if norm > 1e-6 else None
