"""The chart of ``statechart.chart`` on transitions' ``HierarchicalAsyncMachine``.

Guards read the keyword arguments an event is fired with (``fire("detected", needs_plan=False,
has_next_mug=True)``), so the chart holds no job data of its own; the only memory it keeps is the leaf state
a pause interrupted, which ``resume`` returns to.

transitions' AsyncMachine cancels whatever callback is still running when another transition of the same model
starts. ``fire`` therefore serialises every event through one lock and the chart's callbacks only record and
notify (they never await work); the long-running work of a state belongs to the daemon's job runner.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from transitions import MachineError
from transitions.extensions.asyncio import HierarchicalAsyncMachine, NestedAsyncState

from statechart.chart import (
    HISTORY,
    JOB_LEAVES,
    SEPARATOR,
    STATES,
    TRANSITIONS,
    guards_of,
)
from statechart.errors import EventRefused


@dataclass(frozen=True, slots=True)
class Transition:
    """One change of state, as the chart reports it to its listeners (who stamp it on their own clock: the
    chart keeps no time)."""

    trigger: str
    source: str
    dest: str
    detail: dict[str, Any]


class _DottedState(NestedAsyncState):
    separator = SEPARATOR


class _Machine(HierarchicalAsyncMachine):
    state_cls = _DottedState


class _Model:
    """The object transitions attaches its triggers and ``state`` attribute to."""

    state: str


Listener = Callable[[Transition], None]


class StateChart:
    """The loading job's chart. ``state`` is the dotted path of the current leaf, e.g. ``flip.turn``."""

    def __init__(self, *, initial: str = "idle") -> None:
        self._model = _Model()
        self._lock = asyncio.Lock()
        self._listeners: list[Listener] = []
        self.paused_from: str | None = None
        self._machine = _Machine(
            model=self._model,
            states=_state_table(),
            transitions=_transition_table(self),
            initial=initial,
            auto_transitions=False,
            send_event=True,
            ignore_invalid_triggers=False,
        )

    @property
    def state(self) -> str:
        return self._model.state

    def subscribe(self, listener: Listener) -> None:
        """Call ``listener`` after every transition (synchronously: keep it short, never block)."""
        self._listeners.append(listener)

    def triggers(self) -> tuple[str, ...]:
        """Events with a transition out of the current state (guards not evaluated)."""
        return tuple(self._machine.get_triggers(self.state))

    def can(self, trigger: str) -> bool:
        """Whether ``trigger`` could fire now, guards aside (``resume`` also needs a remembered state)."""
        if trigger == "resume":
            return self.state == "paused" and self.paused_from is not None
        return trigger in self.triggers()

    async def fire(self, trigger: str, **guards: Any) -> Transition:
        """Fire one event and return the transition it made; ``EventRefused`` when it made none.

        Keyword arguments are the guard values the trigger's rows consult plus free-form ``detail`` that is
        passed on to listeners (e.g. ``reason`` of a fault)."""
        needed = set(guards_of(trigger)) - set(guards)
        if needed:
            raise TypeError(f"event {trigger} needs guard values for {', '.join(sorted(needed))}")
        async with self._lock:
            source = self.state
            if not self.can(trigger):
                raise EventRefused(trigger, source)
            try:
                moved = await self._model.trigger(trigger, **guards)  # type: ignore[attr-defined]
            except MachineError as e:
                raise EventRefused(trigger, source) from e
            if not moved:
                raise EventRefused(trigger, source)
            if trigger == "pause":
                self.paused_from = source
            elif trigger in ("resume", "stop", "reset"):
                self.paused_from = None
            change = Transition(trigger, source, self.state, dict(guards))
            for listener in self._listeners:
                listener(change)
            return change

    def _resumes_to(self, leaf: str) -> Callable[[Any], bool]:
        return lambda _event: self.paused_from == leaf


def _state_table() -> list[dict[str, Any]]:
    table: list[dict[str, Any]] = []
    for spec in STATES:
        if spec.children:
            table.append({"name": spec.name, "children": list(spec.children), "initial": spec.children[0]})
        else:
            table.append({"name": spec.name})
    return table


def _guard(name: str) -> Callable[[Any], bool]:
    return lambda event: bool(event.kwargs[name])


def _transition_table(chart: StateChart) -> list[dict[str, Any]]:
    table: list[dict[str, Any]] = []
    for spec in TRANSITIONS:
        if spec.dest == HISTORY:
            table.extend(
                {
                    "trigger": spec.trigger,
                    "source": list(spec.sources),
                    "dest": leaf,
                    "conditions": [chart._resumes_to(leaf)],
                }
                for leaf in JOB_LEAVES
            )
            continue
        row: dict[str, Any] = {"trigger": spec.trigger, "source": list(spec.sources), "dest": spec.dest}
        if spec.guard:
            row["conditions"] = [_guard(spec.guard)]
        if spec.unless:
            row["unless"] = [_guard(spec.unless)]
        table.append(row)
    return table
