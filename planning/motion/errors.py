"""Exceptions of motion planning. A refused motion is ``planning.interfaces.MotionRefused`` (shared with the
statechart); these cover bad inputs to the planner's own objects."""

from __future__ import annotations


class InvalidCell(ValueError):
    """The cell layout is malformed; the message names the ``[cell]`` field and what is allowed."""
