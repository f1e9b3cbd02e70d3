"""Exceptions of the simulated world. Messages name the model part, body or servo id and say what to fix."""

from __future__ import annotations

from drivers.sim.plant import PlantStopped


class SimModelError(ValueError):
    """The world could not be built: a malformed URDF, a missing joint, an MJCF MuJoCo refuses."""


class SimWorldStopped(PlantStopped):
    """The physics thread is not running (never started, stopped, or it died on an unstable state). The
    simulated servos read it as their plant gone (``PlantStopped``): they go silent."""
