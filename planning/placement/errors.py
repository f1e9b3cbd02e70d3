"""Exceptions of the placement planner."""

from __future__ import annotations


class InvalidProblem(ValueError):
    """A placement problem (or a planner option) is malformed; the message names the field and what to fix."""
