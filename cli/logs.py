"""Where the command line's structured logs go: stderr, filtered by level, so stdout carries only results."""

from __future__ import annotations

import logging
import sys

LEVELS: dict[str, int] = {
    "debug": logging.DEBUG,
    "info": logging.INFO,
    "warning": logging.WARNING,
    "error": logging.ERROR,
}


def configure_cli_logging(level: str = "info") -> None:
    """Send structlog events at ``level`` or above to stderr (tables, JSON and summaries own stdout)."""
    import structlog  # here, not above: `dishbot --help` builds the parser without it

    structlog.configure(
        logger_factory=structlog.PrintLoggerFactory(sys.stderr),
        wrapper_class=structlog.make_filtering_bound_logger(LEVELS[level]),
    )
