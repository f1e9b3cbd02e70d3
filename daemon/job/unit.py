"""A unit of work: what the job does in one leaf of the chart, with the context keys it uses declared.

As in SMACH (a state's ``input_keys``/``output_keys``) a unit sees the context only through its declared keys:
``Unit.work`` hands ``run`` a view that refuses any other key, so the declarations cannot drift from the code.
A unit ends with an ``Outcome`` whose trigger is one of its declared ``outcomes``.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import ClassVar, cast

from daemon.job.context import JobContext, Outcome
from daemon.job.errors import UndeclaredKey
from daemon.job.services import Services


class Unit(ABC):
    """The work of one chart leaf (``leaf``, e.g. ``flip.turn``). ``reads`` are the context keys it reads,
    ``writes`` those it assigns or changes in place (a written key may also be read); ``outcomes`` the
    triggers it may end with."""

    reads: ClassVar[frozenset[str]] = frozenset()
    writes: ClassVar[frozenset[str]] = frozenset()

    def __init__(self, leaf: str, outcomes: tuple[str, ...]) -> None:
        self.leaf = leaf
        self.outcomes = outcomes

    @property
    def name(self) -> str:
        """The leaf's own name (``turn`` of ``flip.turn``)."""
        return self.leaf.rsplit(".", 1)[-1]

    async def work(self, services: Services, ctx: JobContext) -> Outcome:
        """Run on a view of ``ctx`` that holds only the declared keys; check the outcome is a declared one."""
        outcome = await self.run(services, cast(JobContext, _Keys(ctx, self)))
        if outcome.trigger not in self.outcomes:
            raise RuntimeError(
                f"{self.leaf} ended with {outcome.trigger!r}, not one of its outcomes {list(self.outcomes)}"
            )
        return outcome

    @abstractmethod
    async def run(self, services: Services, ctx: JobContext) -> Outcome:
        """Do the leaf's work."""

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.leaf!r})"


@dataclass(frozen=True, slots=True)
class Stages:
    """A top-level state of the chart and the units of its leaves, in the chart's order, as MoveIt Task
    Constructor lists a task's stages (a state without substates has one: its own)."""

    state: str
    stages: tuple[Unit, ...]

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(u.name for u in self.stages)


class _Keys:
    """A unit's view of the job context: declared keys only."""

    __slots__ = ("_ctx", "_unit")

    def __init__(self, ctx: JobContext, unit: Unit) -> None:
        object.__setattr__(self, "_ctx", ctx)
        object.__setattr__(self, "_unit", unit)

    def __getattr__(self, key: str) -> object:
        unit: Unit = object.__getattribute__(self, "_unit")
        if key not in unit.reads and key not in unit.writes:
            raise UndeclaredKey(f"{unit.leaf} reads context key {key!r}, which it does not declare")
        return getattr(object.__getattribute__(self, "_ctx"), key)

    def __setattr__(self, key: str, value: object) -> None:
        unit: Unit = object.__getattribute__(self, "_unit")
        if key not in unit.writes:
            raise UndeclaredKey(f"{unit.leaf} writes context key {key!r}, which it does not declare")
        setattr(object.__getattribute__(self, "_ctx"), key, value)
