"""Exceptions of the recorder."""

from __future__ import annotations


class RecordingError(ValueError):
    """A recording cannot be written or read (not MCAP, empty, unknown compression, closed recorder)."""


class LiveServerError(OSError):
    """The live Foxglove server cannot start (address in use, not allowed); the message says where and why."""
