"""Exceptions of the replay rig."""

from __future__ import annotations


class ReplayError(ValueError):
    """A replay timeline or fault plan is inconsistent (unknown stream, empty window, time out of range)."""
