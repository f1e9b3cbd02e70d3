"""What one job carries over to the next on the same scene (the mugs on the tray as they were placed, the
counter it knew, the next mug id): written to a job's recording header (``carried``) and taken back by a
replay of a job that continued an earlier job's tray (``carry_over``), so the replay starts as the recorded
daemon did."""

from __future__ import annotations

import dataclasses

from daemon.job.context import JobContext
from daemon.job.errors import CommandRefused


def carry_over(state: str, current: JobContext, earlier: JobContext) -> JobContext:
    """The context to start from when ``earlier`` is what the jobs before left; only while idle (``state``),
    before a job starts (``CommandRefused`` otherwise). The planner options stay ``current``'s."""
    if state != "idle":
        raise CommandRefused(f"cannot carry an earlier job over in state {state}")
    return earlier.next_job(current.planner)


def carried(ctx: JobContext) -> dict[str, object]:
    """What a job started now without a new counter carries over from ``ctx``, for its recording's header."""
    return {
        "on_tray": [dataclasses.asdict(slot) for slot in ctx.on_tray],
        "tray_mugs": [dataclasses.asdict(mug) for mug in ctx.tray_mugs],
        "counter": [dataclasses.asdict(mug) for mug in ctx.counter.values()],
        "next_id": ctx.next_id,
    }
