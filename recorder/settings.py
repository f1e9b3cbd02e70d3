"""The recorder's settings (the config's ``[recording]`` section); light, so the config loads without MCAP."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True, slots=True)
class RecordingConfig:
    """MCAP files in ``dir``: one per job, idle time in rotating files, old files deleted past the limits.

    Small chunks bound what a crash loses. ``max_total_mb`` and ``max_age_days`` of 0 mean no limit."""

    dir: Path
    chunk_size_bytes: int
    compression: str | None
    idle_telemetry_hz: float
    idle_file_s: float
    job_tail_s: float
    max_total_mb: int
    max_age_days: float
