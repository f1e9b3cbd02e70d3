"""What a ``start`` command may ask of the job, validated."""

from __future__ import annotations

from dataclasses import dataclass

from daemon.backend import SetupMug
from daemon.config import PlannerConfig
from planning.placement import PlanOptions


@dataclass(frozen=True, slots=True)
class PlannerRequest:
    """Planner preferences a ``start`` command may set (None keeps the configured value)."""

    method: str | None = None
    cost: str | None = None
    fitness: str | None = None
    time_limit_s: float | None = None
    seed: int | None = None

    def options(self, configured: PlannerConfig) -> PlanOptions:
        """The placement options of a job: these preferences over the configured ones."""
        return PlanOptions(
            method=self.method or configured.method,
            cost=self.cost or configured.cost,
            fitness=self.fitness or configured.fitness,
            time_limit_s=self.time_limit_s or configured.time_limit_s,
            seed=configured.seed if self.seed is None else self.seed,
        )


@dataclass(frozen=True, slots=True)
class StartRequest:
    """A validated ``start`` command body."""

    dataset: int | None = None
    mugs: tuple[SetupMug, ...] | None = None
    planner: PlannerRequest = PlannerRequest()
