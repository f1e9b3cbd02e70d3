"""Exceptions of the arm model: a bad robot description, a bad target or calibration data."""

from __future__ import annotations


class ArmModelError(ValueError):
    """The URDF or its servo assignment cannot be used; the message names the file, joint or frame."""


class InvalidTarget(ValueError):
    """A kinematics target or joint vector is malformed (wrong length, not finite)."""


class CalibrationError(ValueError):
    """Calibration pairs are too few, malformed or give a degenerate fit; the message says which."""
