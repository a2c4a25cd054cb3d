"""The one map interface: every semantic map (OctoMap, voxel grid, point map, ...) is fed and read the same way.

The pipeline builds a list of maps (:func:`semmap.factories.get_map`) and, per frame, hands each the same
:class:`~semmap.types.Observation`; afterwards it reads each as a :class:`~semmap.types.MapCloud`, saves it
(:func:`semmap.io.map_files.save_map_files`, from the map's public arrays) and puts its self-description in the
report.  Nothing outside ``maps/`` needs to know which map it holds.  A user's code queries any map the same way:
:meth:`SemanticMap.class_at` points, :func:`voxels_of_class`.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

from semmap.errors import ConfigError, FormatError
from semmap.maps.registry import MapKind
from semmap.types import LabelSet, MapCloud, Observation


@runtime_checkable
class SemanticMap(Protocol):
    """A 3D semantic map built frame by frame from world points, their sensor origin, colours and classes."""

    #: Which map this is (names its files and its entry in the report).
    kind: MapKind
    #: Voxel edge (or point-filter cell) in metres.
    resolution: float
    #: Classes of the fused distributions; None for geometry and colour only.
    label_set: LabelSet | None
    #: True when :meth:`integrate` uses ``Observation.normals`` (the pipeline computes them only then).
    needs_normals: bool

    def integrate(self, obs: Observation) -> dict[str, float]:
        """Fuse one frame's observation into the map; returns milliseconds per step (for the report)."""
        ...

    def cloud(self) -> MapCloud:
        """Occupied voxels (or points) as flat arrays, in a deterministic order."""
        ...

    def class_at(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Most probable class (uint16, EMPTY_LABEL where none) and its probability (float32) at each (N, 3) world
        point: the class :meth:`cloud` reports for the occupied voxel (or point cell) holding it."""
        ...

    def state(self) -> dict[str, np.ndarray]:
        """Everything integration changed, by the checkpoint schema's stable names (a checkpoint's map)."""
        ...

    def restore(self, state: dict[str, np.ndarray]) -> None:
        """Continue from :meth:`state` of a map built with the same parameters (FormatError when it does not fit)."""
        ...

    def describe(self) -> dict:
        """Counts and memory of the map for the report (JSON-serialisable)."""
        ...


def voxels_of_class(m: SemanticMap, cls: int | str) -> np.ndarray:
    """Centres (M, 3) of the occupied voxels (or points) of ``m`` whose most probable class is ``cls``: a class id,
    or a class name of the map's label set."""
    if isinstance(cls, str):
        if m.label_set is None:
            raise ConfigError(f"class {cls!r} asked of a map without a label set")
        cls = m.label_set.id_of(cls)
    if m.label_set is not None and not 0 <= int(cls) < len(m.label_set):
        raise ConfigError(f"class id {cls} is outside the map's label set (0..{len(m.label_set) - 1})")
    cloud = m.cloud()
    return cloud.centers[cloud.labels == int(cls)]


#: One map's checkpoint state: its arrays and counters (0-d arrays) by stable public names (the checkpoint schema).
MapState = dict[str, np.ndarray]


def check_state(state: MapState, names: tuple[str, ...], what: str) -> None:
    """A :class:`FormatError` naming what a checkpoint ``state`` of ``what`` lacks (another semmap version)."""
    missing = [n for n in names if n not in state]
    if missing:
        raise FormatError(f"checkpoint of {what} lacks {', '.join(missing)} (written by another semmap version?)")


def restore_arrays(obj, fields: dict[str, str], state: MapState, what: str, holder: str) -> None:
    """Set ``obj``'s attributes from a checkpoint ``state`` by the schema ``fields`` (name -> attribute), each array
    checked against the one ``obj`` holds now (dtype and trailing shape): a FormatError names ``what`` otherwise."""
    for name, attr in fields.items():
        have, got = getattr(obj, attr), np.asarray(state[name])
        if got.dtype != have.dtype or got.shape[1:] != have.shape[1:]:
            raise FormatError(f"checkpoint of {what}: {name} is {got.dtype}{got.shape}, this {holder} keeps "
                              f"{have.dtype}(..., {have.shape[1:]}) (another configuration?)")
        setattr(obj, attr, np.ascontiguousarray(got))
