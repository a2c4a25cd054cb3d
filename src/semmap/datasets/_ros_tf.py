"""A transform tree built from ROS ``/tf`` and ``/tf_static`` messages (or a pose topic), queried for
``T_world_cam`` at a frame's timestamp.

Each edge parent -> child holds time-stamped transforms ``T_parent_child``; a lookup walks from the camera frame up
its parents to the world frame, interpolating every dynamic edge at the query time (slerp, as TUM ground truth is
interpolated) and composing. Static edges hold one transform for all times.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from semmap.types import interpolate_pose

#: Longest gap between two samples of an edge that a lookup interpolates across (seconds).
MAX_INTERPOLATION_GAP = 0.5


@dataclass
class _Edge:
    parent: str
    static: bool
    stamps: list[float] = field(default_factory=list)
    poses: list[np.ndarray] = field(default_factory=list)
    _sorted: tuple[np.ndarray, np.ndarray] | None = None

    def add(self, stamp: float, T: np.ndarray) -> None:
        self.stamps.append(stamp)
        self.poses.append(T)
        self._sorted = None

    def at(self, t: float, tolerance: float) -> tuple[np.ndarray | None, str]:
        """``T_parent_child`` at ``t``, or None and why."""
        if self.static:
            return self.poses[-1], ""
        if self._sorted is None:
            order = np.argsort(self.stamps, kind="stable")
            self._sorted = (np.asarray(self.stamps)[order], np.stack(self.poses)[order])
        stamps, poses = self._sorted
        if t < stamps[0] - tolerance or t > stamps[-1] + tolerance:
            return None, f"t={t:.3f} s is outside the transforms' time range [{stamps[0]:.3f}, {stamps[-1]:.3f}] s"
        j = int(np.searchsorted(stamps, t, side="right"))
        if j == 0:
            return poses[0], ""
        if j == len(stamps):
            return poses[-1], ""
        i = j - 1
        if stamps[i] == t:
            return poses[i], ""
        gap = stamps[j] - stamps[i]
        if gap > MAX_INTERPOLATION_GAP:
            return None, f"no transform within {MAX_INTERPOLATION_GAP} s around t={t:.3f} s (gap of {gap:.2f} s)"
        return interpolate_pose(poses[i], poses[j], (t - stamps[i]) / gap), ""


class TransformTree:
    """Transforms between named frames over time; each child frame has one parent."""

    def __init__(self) -> None:
        self._edges: dict[str, _Edge] = {}

    def add(self, parent: str, child: str, stamp: float, T_parent_child: np.ndarray, *, static: bool = False
            ) -> None:
        """Record ``T_parent_child`` at ``stamp``; a child that changes parent keeps its first one."""
        parent, child = parent.lstrip("/"), child.lstrip("/")
        edge = self._edges.get(child)
        if edge is None:
            edge = self._edges[child] = _Edge(parent, static)
        elif edge.parent != parent:
            return
        edge.add(stamp, T_parent_child)

    def __contains__(self, frame: str) -> bool:
        frame = frame.lstrip("/")
        return frame in self._edges or any(e.parent == frame for e in self._edges.values())

    @property
    def frames(self) -> list[str]:
        return sorted({*self._edges, *(e.parent for e in self._edges.values())})

    def root_of(self, frame: str) -> str:
        """The topmost ancestor of ``frame``."""
        frame, seen = frame.lstrip("/"), set()
        while frame in self._edges and frame not in seen:
            seen.add(frame)
            frame = self._edges[frame].parent
        return frame

    def lookup(self, world: str, camera: str, t: float, tolerance: float) -> tuple[np.ndarray | None, str]:
        """``T_world_cam`` at ``t`` (None and why when the chain is missing or has no transform near ``t``)."""
        world, frame = world.lstrip("/"), camera.lstrip("/")
        T = np.eye(4)
        seen = set()
        while frame != world:
            edge = self._edges.get(frame)
            if edge is None or frame in seen:
                return None, f"no chain of transforms from {camera!r} up to {world!r}"
            seen.add(frame)
            T_edge, why = edge.at(t, tolerance)
            if T_edge is None:
                return None, f"{edge.parent} -> {frame}: {why}"
            T = T_edge @ T
            frame = edge.parent
        return T, ""
