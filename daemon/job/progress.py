"""Whether the job is making progress: when its current state was entered, against that state's time bound.

A job state that stays entered past its bound (``[daemon.state_bounds_s]``) has stalled: a device that no
longer answers, a wait that never ends. The runner faults the job then, and the daemon stops pinging the
systemd watchdog from the moment the bound passes until the job has left the state, so a stall that even the
fault cannot end (the control task stuck too) gets the daemon restarted instead of pinging on. The bound of
the top-level state (``side_grasp``) runs from when it was entered, over all its leaves; a leaf with a bound
of its own (``side_grasp.close``) is held to that from when the leaf was entered too.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from statechart.chart import JOB_STATES, top_level

# Placement planning may take its time limit (a start command may ask for up to 600 s) and motion planning
# some more: plan's bound is never below twice the limit plus this.
_PLAN_MARGIN_S = 10.0


@dataclass(frozen=True, slots=True)
class Deadline:
    """When ``state`` passes its ``bound_s`` (on the job's clock)."""

    state: str
    bound_s: float
    at: float

    @property
    def reason(self) -> str:
        return f"state {self.state} exceeded its {self.bound_s:g} s bound"


class Progress:
    """Tracks the entries of the job's states (``entered``) and the deadline of the one it is in."""

    def __init__(self, bound_of: Callable[[str], float | None]) -> None:
        self._bound_of = bound_of
        self._leaf = ""
        self._leaf_at = 0.0
        self._state_at = 0.0
        self._plan_limit_s = 0.0

    def entered(self, source: str, dest: str, now: float, *, plan_time_limit_s: float = 0.0) -> None:
        """The chart went from ``source`` to ``dest`` at ``now``; a job's planner time limit widens plan's
        bound."""
        if top_level(dest) != top_level(source) or not self._leaf:
            self._state_at = now
        self._leaf = dest
        self._leaf_at = now
        self._plan_limit_s = plan_time_limit_s

    def deadline(self) -> Deadline | None:
        """The first bound the current state will pass (None: not a job state, so nothing to pass)."""
        state = top_level(self._leaf)
        if state not in JOB_STATES:
            return None
        deadlines = []
        bound = self._bound_of(state)
        if bound is not None:
            if state == "plan":
                bound = max(bound, 2.0 * self._plan_limit_s + _PLAN_MARGIN_S)
            deadlines.append(Deadline(state, bound, self._state_at + bound))
        leaf_bound = self._bound_of(self._leaf) if self._leaf != state else None
        if leaf_bound is not None:
            deadlines.append(Deadline(self._leaf, leaf_bound, self._leaf_at + leaf_bound))
        return min(deadlines, key=lambda d: d.at, default=None)

    def overdue(self, now: float) -> Deadline | None:
        """The bound the current state has passed at ``now``, if it has."""
        deadline = self.deadline()
        return deadline if deadline is not None and now >= deadline.at else None
