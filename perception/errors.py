"""Exceptions of the perception package. Messages name the file, field or image and say what to do."""

from __future__ import annotations

from drivers.errors import DriverError


class PerceptionError(ValueError):
    """Base of perception's input errors."""


class FrameError(PerceptionError):
    """A depth frame cannot be used: wrong shape, no valid pixels, no table in view."""


class CalibrationError(PerceptionError):
    """A camera description or calibration file is missing, malformed or inconsistent."""


class BoardNotFound(CalibrationError):
    """The calibration board could not be found (or not enough of it) in the image."""


class CameraFault(DriverError):
    """The camera gave no usable frame within the retries: none in time, too old, or unusable. The message
    starts with ``camera:`` and says which (``camera: no frame within 2.0 s``); the job faults with it."""
