"""Exceptions of the daemon layer."""

from __future__ import annotations

from validation import Invalid


class UsageError(ValueError):
    """Bad command-line input or a bad file named on the command line; the CLI exits 2 with this message."""


class ConfigError(Invalid):
    """A configuration value is missing or out of range; the message names the field and the allowed range."""
