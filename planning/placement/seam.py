"""The placement planner as the daemon's job sees it: a picklable callable from a problem to a result."""

from __future__ import annotations

from typing import Protocol

from planning.placement.context import PlanOptions
from planning.placement.planner import PlanResult
from planning.placement.problem import Problem


class PlacementPlanner(Protocol):
    """Plans where each counter mug goes on the tray and in which order (``planning.placement.plan``).
    The daemon may run it in another process: an implementation must pickle."""

    def __call__(self, problem: Problem, options: PlanOptions, /) -> PlanResult: ...
