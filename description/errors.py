"""Exceptions of the description layer: a description that cannot be right."""

from __future__ import annotations


class InvalidCell(ValueError):
    """The cell layout (counter, flip area, tray, camera) is malformed; the message names the config field
    (``cell.counter_region_m``, ``camera.pitch_rad``, ...) and what is allowed."""
