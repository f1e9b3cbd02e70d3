"""The job's units of work: one per leaf of the chart, checked against it when the package is imported, and
each confined to the context keys it declares."""

from __future__ import annotations

import asyncio
import importlib.util
from collections.abc import Iterable
from dataclasses import replace
from pathlib import Path
from types import ModuleType

import pytest

from daemon.config import load_config
from daemon.job import (
    STATES,
    UNITS,
    ChartMismatch,
    JobContext,
    Outcome,
    Services,
    UndeclaredKey,
    Unit,
    registry,
)
from daemon.job.manipulation import FLIP, FollowSteps
from perception import associate
from planning.placement import PlanOptions
from statechart import chart
from tests.fakes.job import make_backend, make_world


def _fresh_registry() -> ModuleType:
    """Import ``daemon.job.registry`` again, as a new module, against the chart as it is now."""
    spec = importlib.util.spec_from_file_location("daemon.job._registry_again", Path(registry.__file__))
    assert spec is not None
    assert spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _chart_with(monkeypatch: pytest.MonkeyPatch, name: str, children: tuple[str, ...]) -> None:
    states = tuple(replace(s, children=children) if s.name == name else s for s in chart.STATES)
    monkeypatch.setattr(chart, "STATES", states)


def test_every_leaf_of_the_job_has_one_unit_listed_in_the_charts_order() -> None:
    assert tuple(UNITS) == chart.JOB_LEAVES
    assert tuple(s.state for s in STATES) == chart.JOB_STATES
    assert FLIP.names == ("transit", "turn", "set_down", "release", "regrasp", "close", "verify", "lift")
    assert [type(u).__name__ for u in UNITS.values() if u.leaf.startswith("place.")] == [
        "FollowSteps",
        "FollowSteps",
        "PlaceRelease",
        "PlaceRetreat",
    ]
    assert UNITS["flip.turn"].outcomes == ("next", "mug_dropped")  # it carries the mug: the FSR is watched
    assert UNITS["flip.regrasp"].outcomes == ("next",)


def test_a_chart_leaf_without_a_unit_fails_the_import_naming_it(monkeypatch: pytest.MonkeyPatch) -> None:
    flip = next(s for s in chart.STATES if s.name == "flip")
    _chart_with(monkeypatch, "flip", (*flip.children, "spin"))
    with pytest.raises(
        ChartMismatch,
        match=r"^the job's units do not match statechart.chart: no unit for the leaves flip.spin$",
    ):
        _fresh_registry()


def test_a_unit_for_a_leaf_the_chart_lacks_fails_the_import_naming_it(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    _chart_with(monkeypatch, "place", ("transit", "descend", "release"))
    with pytest.raises(ChartMismatch, match=r": units for leaves the chart does not have: place.retreat$"):
        _fresh_registry()


def test_a_new_job_state_without_units_fails_the_import(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(chart, "STATES", (*chart.STATES, chart.StateSpec("rinse", "rinse the mug")))
    monkeypatch.setattr(chart, "JOB_STATES", (*chart.JOB_STATES, "rinse"))
    with pytest.raises(ChartMismatch, match=r": no units for the states rinse$"):
        _fresh_registry()


def test_stages_out_of_the_charts_order_are_refused() -> None:
    flip = replace(FLIP, stages=(FLIP.stages[1], FLIP.stages[0], *FLIP.stages[2:]))
    states = tuple(flip if s.state == "flip" else s for s in STATES)
    with pytest.raises(
        ChartMismatch, match=r": flip lists flip.turn, flip.transit, .*; the chart's order is "
    ):
        registry.check_against_chart(states)


class _Finishes(FollowSteps):
    reads = frozenset({"cycle", "backlog"})

    def __init__(self, leaf: str) -> None:
        Unit.__init__(self, leaf, ("next", "finished"))


def test_a_unit_ending_with_an_event_its_leaf_does_not_take_or_declaring_an_unknown_key_is_refused() -> None:
    odd = replace(FLIP, stages=tuple(_Finishes(u.leaf) if u.leaf == "flip.turn" else u for u in FLIP.stages))
    states = tuple(odd if s.state == "flip" else s for s in STATES)
    with pytest.raises(ChartMismatch) as e:
        registry.check_against_chart(states)
    assert str(e.value) == (
        "the job's units do not match statechart.chart: flip.turn may end with finished, which the chart "
        "does not take there; flip.turn declares context keys JobContext does not have: backlog"
    )


class _Peeks(Unit):
    """Declares that it reads the counter, then reads or writes something else."""

    reads = frozenset({"counter"})
    writes = frozenset({"needs_plan"})

    def __init__(self, action: str) -> None:
        super().__init__("detect", ("detected",))
        self.action = action

    async def run(self, services: Services, ctx: JobContext) -> Outcome:
        if self.action == "read":
            return Outcome("detected", {"queue": len(ctx.queue)})
        if self.action == "write":
            ctx.counter = {}
        if self.action == "outcome":
            return Outcome("planned")
        ctx.needs_plan = not ctx.counter
        return Outcome("detected")


def _work(unit: Unit) -> tuple[Outcome, JobContext]:
    world = make_world(1)
    services = Services(
        make_backend(world), load_config(), lambda t, p: None, associate, state=lambda: "detect"
    )
    ctx = JobContext(planner=PlanOptions(), needs_plan=False)
    return asyncio.run(unit.work(services, ctx)), ctx


def test_a_unit_sees_only_the_keys_it_declares() -> None:
    outcome, ctx = _work(_Peeks("declared"))
    assert (outcome.trigger, ctx.needs_plan) == ("detected", True)
    with pytest.raises(UndeclaredKey, match=r"^detect reads context key 'queue', which it does not declare$"):
        _work(_Peeks("read"))
    with pytest.raises(
        UndeclaredKey, match=r"^detect writes context key 'counter', which it does not declare$"
    ):
        _work(_Peeks("write"))


def test_a_unit_ending_with_an_outcome_it_does_not_declare_is_an_error() -> None:
    with pytest.raises(
        RuntimeError, match=r"^detect ended with 'planned', not one of its outcomes \['detected'\]$"
    ):
        _work(_Peeks("outcome"))


def _units_table() -> str:
    """The table of units in docs/daemon.md, from the code."""

    def keys(names: Iterable[str]) -> str:
        return ", ".join(f"`{k}`" for k in sorted(names)) or "-"

    rows = [
        "| unit | leaves | reads only | writes (and reads) | ends with |",
        "| --- | --- | --- | --- | --- |",
    ]
    classes: dict[type[Unit], list[Unit]] = {}
    for unit in UNITS.values():
        classes.setdefault(type(unit), []).append(unit)
    for cls, units in classes.items():
        by_state: dict[str, list[str]] = {}
        for u in units:
            state, _, leaf = u.leaf.partition(".")
            by_state.setdefault(state, []).append(leaf)
        leaves = "; ".join(f"`{s}`" + (f": {', '.join(ls)}" if any(ls) else "") for s, ls in by_state.items())
        u = units[0]
        outcomes = keys({o for u in units for o in u.outcomes})
        rows.append(
            f"| `{cls.__name__}` | {leaves} | {keys(u.reads - u.writes)} | {keys(u.writes)} | {outcomes} |"
        )
    return "\n".join(rows)


def test_the_units_table_in_the_docs_is_the_code() -> None:
    docs = (Path(__file__).parents[2] / "docs" / "daemon.md").read_text()
    assert _units_table() in docs, _units_table()
