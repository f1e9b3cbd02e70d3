"""The planning worker's priority: below the daemon's on the wall clock, the daemon's own on a simulated one
(where the loop waits for every plan, so the planner is the job's critical path)."""

from __future__ import annotations

import os

from cli.commands.run import planning_pool


def niceness() -> int:
    """Runs in the planning worker process."""
    return os.nice(0)


def test_the_worker_plans_in_the_background_on_the_wall_clock() -> None:
    with planning_pool("warning") as pool:
        assert pool.submit(niceness).result(timeout=60) == min(os.nice(0) + 10, 19)


def test_the_worker_plans_at_the_daemons_priority_for_a_simulated_clock() -> None:
    with planning_pool("warning", background=False) as pool:
        assert pool.submit(niceness).result(timeout=60) == os.nice(0)
