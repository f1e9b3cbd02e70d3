"""Exceptions of the simulated world. Messages name the model part, body or servo id and say what to fix."""

from __future__ import annotations


class SimModelError(ValueError):
    """The world could not be built: a malformed URDF, a missing joint, an MJCF MuJoCo refuses."""


class SimWorldStopped(RuntimeError):
    """The physics thread is not running (never started, stopped, or it died on an unstable state)."""
