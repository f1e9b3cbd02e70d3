"""Where the command line's structured logs go: stderr, filtered by level, so stdout carries only results."""

from __future__ import annotations

import sys
from typing import Final

# The ``--log-level`` choices, least severe first: the names of ``logging``'s levels, in lower case (logging
# itself is imported only when logs are configured: ``dishbot --help`` does without it).
LEVELS: Final = ("debug", "info", "warning", "error")


def configure_cli_logging(level: str = "info") -> None:
    """Send structlog events at ``level`` or above to stderr (tables, JSON and summaries own stdout)."""
    import logging  # here, not above, as structlog: `dishbot --help` builds the parser without them

    import structlog

    structlog.configure(
        logger_factory=structlog.PrintLoggerFactory(sys.stderr),
        wrapper_class=structlog.make_filtering_bound_logger(logging.getLevelNamesMapping()[level.upper()]),
    )
