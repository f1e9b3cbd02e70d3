"""Exceptions of the job: a refused command, and the bugs the units' checks catch."""

from __future__ import annotations


class CommandRefused(ValueError):
    """A command that is not allowed now or carries bad values; nothing changed."""


class ChartMismatch(RuntimeError):
    """The job's units do not match the chart's states (raised on import); the message lists every
    difference."""


class UndeclaredKey(AttributeError):
    """A unit used a context key it does not declare: a bug in the unit (or its declaration)."""
