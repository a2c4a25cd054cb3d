"""Realism presets of the simulator (``semmap simulate --realism``): how real its sensors and motion look.

- ``clean``: today's simulator, byte for byte: exact geometry, the light Kinect-like depth noise of
  :class:`semmap.sim.noise.KinectNoise` (or none with ``--no-noise``); the tests that check exact geometry and the
  demo's digest use it, and it stays the default;
- ``kinect``: a Kinect v1 calibrated against 7-Scenes (``benchmarks/bench_realism.py``): structured-light depth
  (:class:`semmap.sim.depth_sensor.StructuredLight`); the tracking, object and fusion benchmarks use it;
- ``hard``: a worse day for the same sensor: more noise, wider edges, more holes.

A preset composes the depth sensor with the colour camera (:mod:`semmap.sim.camera_model`) and the hand-held
motion (:mod:`semmap.sim.hand_motion`) of the same name.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

from semmap.errors import SimulationError
from semmap.sim.depth_sensor import DepthSensor, StructuredLight, TimeOfFlight
from semmap.sim.noise import KinectNoise

#: The presets, in order of difficulty; the first is the default.
REALISMS: tuple[str, ...] = ("clean", "kinect", "hard")
DEFAULT_REALISM = REALISMS[0]
#: What each preset simulates, in words (reports name the preset of their frames with it).
SUMMARIES: dict[str, str] = {
    "clean": "exact geometry, colour and poses, light Kinect-like depth noise",
    "kinect": "a Kinect v1 calibrated on 7-Scenes: structured-light depth, colour camera, hand-held motion",
    "hard": "the Kinect v1 preset on a worse day: more depth noise, wider edges, more holes",
}

#: A Kinect v1 unit's systematic errors, from the literature (docs/realism.md, "Systematic depth errors"), not tuned
#: on any tracking number: a disparity distortion of 0.1 px at the image corners (r^2; 2 cm at 3 m, 3.6 cm at 4 m)
#: plus a 0.03 px smooth field (Herrera et al. 2012; Smisek et al. 2011; Teichman et al. 2013), and true IR
#: intrinsics 1 % and (3, 2) px off the nominal f = 585 px, (320, 240) that 7-Scenes publishes.
KINECT_SYSTEMATIC = {"distortion_px": 0.1, "distortion_field_px": 0.03, "focal_error": 0.01,
                     "principal_offset_px": (3.0, 2.0)}
#: ... and twice those for ``hard``: a worse unit, further from its nominal calibration.
HARD_SYSTEMATIC = {"distortion_px": 0.2, "distortion_field_px": 0.06, "focal_error": 0.02,
                   "principal_offset_px": (8.0, 5.0)}
#: Kinect v1 as 7-Scenes recorded it (noise and holes tuned by benchmarks/bench_realism.py; see docs/realism.md).
KINECT_DEPTH = StructuredLight(**KINECT_SYSTEMATIC)
#: The same sensor on a worse day: noisier disparity, rougher edges, more dropout on difficult materials.
HARD_DEPTH = dataclasses.replace(KINECT_DEPTH, sigma_disp_px=0.08, sigma_corr_px=0.07, angle_gain=0.1,
                                 lateral_px=1.0, edge_drop_p=0.5, dark_drop_p=0.8, specular_drop_p=0.5,
                                 far_drop_p=0.5, grazing_deg=80.0, grazing_ramp_deg=10.0, shadow_slack_px=0.0,
                                 **HARD_SYSTEMATIC)

DepthModel = KinectNoise | StructuredLight | TimeOfFlight


@dataclass(frozen=True)
class Realism:
    """One preset: its name, the depth model (seed 0; :meth:`depth_model` seeds it) and the colour and motion
    parameters (None: the renderer's exact colour and the trajectory generator's own motion)."""

    name: str
    depth: DepthModel | None
    colour: Any = None
    motion: Any = None

    def depth_model(self, seed: int, noise: bool = True) -> DepthModel | None:
        """The depth model seeded with ``seed``; None (exact depth) when ``noise`` is off."""
        if self.depth is None or not noise:
            return None
        return dataclasses.replace(self.depth, seed=int(seed))

    def colour_camera(self, seed: int) -> Any:
        """The colour camera with its random stream ``seed`` (None: the exact image)."""
        return None if self.colour is None else self.colour.with_seed(int(seed))

    @property
    def exact_geometry(self) -> bool:
        """Whether frames are today's clean ones (exact colour and poses, at most the light depth noise)."""
        return self.name == DEFAULT_REALISM


_DEPTH: dict[str, DepthModel] = {"clean": KinectNoise(), "kinect": KINECT_DEPTH, "hard": HARD_DEPTH}


def realism(name: str | Realism | None = None) -> Realism:
    """The preset called ``name`` (default ``clean``); a :class:`Realism` is returned as it is."""
    if isinstance(name, Realism):
        return name
    name = DEFAULT_REALISM if name is None else str(name)
    if name not in REALISMS:
        raise SimulationError(f"unknown --realism {name!r}; choose one of {', '.join(REALISMS)}")
    return Realism(name, _DEPTH[name], colour=_colour_params(name), motion=_motion_params(name))


def with_depth(preset: Realism, depth: DepthSensor | KinectNoise | None) -> Realism:
    """``preset`` with another depth model (e.g. :class:`TimeOfFlight`, or tuned parameters)."""
    return dataclasses.replace(preset, depth=depth)


def _colour_params(name: str) -> Any:
    """Colour camera parameters of preset ``name`` (:mod:`semmap.sim.camera_model`; seeded per scene by
    :meth:`Realism.colour_camera`)."""
    from semmap.sim.camera_model import colour_params

    return colour_params(name)


def _motion_params(name: str) -> Any:
    """Hand-held motion parameters of preset ``name`` (:mod:`semmap.sim.hand_motion`)."""
    from semmap.sim.hand_motion import motion_params

    return motion_params(name)
