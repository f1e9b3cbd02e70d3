"""Every row of the chart, every guard both ways, and every refused event, on the real async machine."""

from __future__ import annotations

import asyncio
from typing import Any

import pytest

from statechart.chart import (
    CARRYING,
    CYCLE_PHASES,
    HISTORY,
    JOB_LEAVES,
    LEAVES,
    STATES,
    TRANSITIONS,
    TRIGGERS,
    TransitionSpec,
    guards_of,
)
from statechart.errors import EventRefused
from statechart.machine import StateChart, Transition
from statechart.mermaid import to_mermaid


def _run(coro: Any) -> Any:
    return asyncio.run(coro)


def _leaves_of(source: str) -> tuple[str, ...]:
    spec = next((s for s in STATES if s.name == source), None)
    return spec.leaves if spec else (source,)


def _entry_leaf(dest: str) -> str:
    return _leaves_of(dest)[0]


def _winning_guards(spec: TransitionSpec, source: str) -> dict[str, bool]:
    """Guard values that make ``spec`` the first matching row for ``source``."""
    values = dict.fromkeys(guards_of(spec.trigger), False)
    if spec.guard:
        values[spec.guard] = True
    if spec.unless:
        values[spec.unless] = False
    for earlier in TRANSITIONS[: TRANSITIONS.index(spec)]:
        if earlier.trigger == spec.trigger and source in _expand(earlier.sources) and earlier.guard:
            values[earlier.guard] = False
    return values


def _expand(sources: tuple[str, ...]) -> set[str]:
    return {leaf for s in sources for leaf in _leaves_of(s)} | set(sources)


ROWS = [
    (spec, leaf)
    for spec in TRANSITIONS
    if spec.dest != HISTORY
    for source in spec.sources
    for leaf in _leaves_of(source)
]


@pytest.mark.parametrize(("spec", "leaf"), ROWS, ids=[f"{s.trigger}:{leaf}->{s.dest}" for s, leaf in ROWS])
def test_each_transition_reaches_its_destination(spec: TransitionSpec, leaf: str) -> None:
    async def go() -> Transition:
        chart = StateChart(initial=leaf)
        return await chart.fire(spec.trigger, **_winning_guards(spec, leaf))

    change = _run(go())
    assert (change.source, change.dest) == (leaf, _entry_leaf(spec.dest))


GUARDED = [spec for spec in TRANSITIONS if spec.guard or spec.unless]


@pytest.mark.parametrize("spec", GUARDED, ids=[f"{s.trigger}:{s.sources[0]}->{s.dest}" for s in GUARDED])
def test_a_guard_that_does_not_hold_sends_the_event_elsewhere(spec: TransitionSpec) -> None:
    leaf = _leaves_of(spec.sources[0])[0]
    guards = _winning_guards(spec, leaf)
    flipped = spec.guard or spec.unless
    assert flipped is not None
    guards[flipped] = not guards[flipped]

    async def go() -> str:
        chart = StateChart(initial=leaf)
        return (await chart.fire(spec.trigger, **guards)).dest

    assert _run(go()) != _entry_leaf(spec.dest)


def test_detect_with_no_plan_change_and_no_mug_left_is_done() -> None:
    async def go() -> str:
        chart = StateChart(initial="detect")
        return (await chart.fire("detected", needs_plan=False, has_next_mug=False)).dest

    assert _run(go()) == "done"


def _allowed(trigger: str, leaf: str) -> bool:
    return any(t.trigger == trigger and leaf in _expand(t.sources) for t in TRANSITIONS)


REFUSED = [
    (trigger, leaf)
    for trigger in TRIGGERS
    for leaf in LEAVES
    if trigger != "resume" and not _allowed(trigger, leaf)
]


@pytest.mark.parametrize(("trigger", "leaf"), REFUSED, ids=[f"{t}@{s}" for t, s in REFUSED])
def test_an_event_not_allowed_in_a_state_is_refused_and_changes_nothing(trigger: str, leaf: str) -> None:
    async def go() -> StateChart:
        chart = StateChart(initial=leaf)
        with pytest.raises(EventRefused, match=f"^cannot {trigger} in state {leaf}$"):
            await chart.fire(trigger, **dict.fromkeys(guards_of(trigger), True))
        return chart

    assert _run(go()).state == leaf


@pytest.mark.parametrize("leaf", JOB_LEAVES)
def test_resume_returns_to_the_leaf_the_pause_interrupted(leaf: str) -> None:
    async def go() -> list[tuple[str, str]]:
        chart = StateChart(initial=leaf)
        seen: list[tuple[str, str]] = []
        chart.subscribe(lambda t: seen.append((t.source, t.dest)))
        await chart.fire("pause")
        await chart.fire("resume")
        return seen

    assert _run(go()) == [(leaf, "paused"), ("paused", leaf)]


def test_resume_is_refused_outside_paused_and_after_stop() -> None:
    async def go() -> None:
        chart = StateChart(initial="flip.turn")
        with pytest.raises(EventRefused, match=r"^cannot resume in state flip.turn$"):
            await chart.fire("resume")
        await chart.fire("pause")
        await chart.fire("stop")
        assert chart.state == "idle"
        with pytest.raises(EventRefused, match=r"^cannot resume in state idle$"):
            await chart.fire("resume")

    _run(go())


@pytest.mark.parametrize("leaf", LEAVES)
def test_estop_is_accepted_in_every_state(leaf: str) -> None:
    async def go() -> str:
        chart = StateChart(initial=leaf)
        return (await chart.fire("estop")).dest

    assert _run(go()) == "estop"


def test_fault_is_left_only_by_reset() -> None:
    async def go() -> None:
        chart = StateChart(initial="place.descend")
        await chart.fire("fault", reason="servo 3 overload")
        assert set(chart.triggers()) == {"fault", "estop", "reset"}
        for trigger in ("start", "resume", "stop", "pause"):
            with pytest.raises(EventRefused):
                await chart.fire(trigger)
        await chart.fire("reset")
        assert chart.state == "idle"

    _run(go())


def test_firing_without_the_guard_values_is_a_programming_error() -> None:
    async def go() -> None:
        chart = StateChart(initial="detect")
        with pytest.raises(
            TypeError, match=r"^event detected needs guard values for has_next_mug, needs_plan$"
        ):
            await chart.fire("detected")

    _run(go())


def test_a_whole_job_of_one_mug_walks_the_documented_path() -> None:
    async def go() -> list[str]:
        chart = StateChart()
        path = [chart.state]
        chart.subscribe(lambda t: path.append(t.dest))
        await chart.fire("start")
        await chart.fire("detected", needs_plan=True, has_next_mug=True)
        await chart.fire("planned", has_next_mug=True)
        while chart.state != "detect":
            if chart.state.endswith("verify"):
                await chart.fire("verified", grasp_held=True)
            else:
                await chart.fire("next")
        await chart.fire("detected", needs_plan=False, has_next_mug=False)
        return path

    path = _run(go())
    assert path[:4] == ["idle", "detect", "plan", "side_grasp.approach"]
    assert path[-2:] == ["detect", "done"]
    assert [p for p in path if "." in p] == list(CYCLE_PHASES)


def test_listeners_see_the_detail_an_event_carries() -> None:
    async def go() -> Transition:
        chart = StateChart(initial="idle")
        seen: list[Transition] = []
        chart.subscribe(seen.append)
        await chart.fire("fault", reason="bus lost on /dev/ttyUSB0")
        return seen[0]

    change = _run(go())
    assert change.detail == {"reason": "bus lost on /dev/ttyUSB0"}
    assert (change.trigger, change.source, change.dest) == ("fault", "idle", "fault")


def test_carrying_states_are_manipulation_leaves() -> None:
    assert set(CARRYING) <= set(CYCLE_PHASES)


def test_mermaid_draws_every_state_and_every_event() -> None:
    text = to_mermaid()
    assert text.startswith("stateDiagram-v2\n")
    for spec in STATES:
        assert spec.name in text
    for trigger in TRIGGERS:
        assert f": {trigger}" in text
    assert "detect --> plan: detected [needs_plan]" in text
    assert "paused --> job: resume (back where it stopped)" in text
