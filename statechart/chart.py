"""The loading job's statechart as data: states (with substates), events, guards and transitions.

The flow follows the thesis's processing flowchart (Fig 3.6) and manipulation flow (Fig 4.18): detect the
mugs, plan their tray slots, then for each mug side-grasp it, turn it upside down on the flip area, regrasp it
and place it on the tray; after each mug the counter is looked at again (``detect``), which replans when the
set of mugs changed. A failed grasp or a dropped mug leads to ``recover_lost_mug`` (§4.3.1), which looks for
the mug again and either grasps it where it now lies or replans the remaining mugs around those on the tray.

Nothing here does I/O: ``statechart.machine`` turns this table into a ``HierarchicalAsyncMachine``,
``statechart.mermaid`` draws it, and the daemon's job runner does each state's work.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Final

SEPARATOR: Final = "."

# A transition whose destination is HISTORY returns to the leaf state the chart was paused in.
HISTORY: Final = "<history>"


@dataclass(frozen=True, slots=True)
class StateSpec:
    """One top-level state and its substates (entered at the first one)."""

    name: str
    doc: str
    children: tuple[str, ...] = ()

    @property
    def leaves(self) -> tuple[str, ...]:
        """The full paths of the states the chart can actually rest in."""
        if not self.children:
            return (self.name,)
        return tuple(f"{self.name}{SEPARATOR}{c}" for c in self.children)


@dataclass(frozen=True, slots=True)
class TransitionSpec:
    """``trigger`` moves the chart from any of ``sources`` (a state or any substate of it) to ``dest``
    when ``guard`` is true (or, with ``unless``, false). For one trigger and source, the first row whose guard
    holds wins, so an unguarded row after guarded ones is the fallback."""

    trigger: str
    sources: tuple[str, ...]
    dest: str
    guard: str | None = None
    unless: str | None = None


STATES: Final[tuple[StateSpec, ...]] = (
    StateSpec("idle", "waiting for a start command; the arm holds still"),
    StateSpec("detect", "look at the counter and associate what is seen with the mugs already known"),
    StateSpec("plan", "plan tray slots for the mugs on the counter, keeping the mugs already on the tray"),
    StateSpec(
        "side_grasp",
        "take the current mug from the counter with a side grasp",
        ("approach", "close", "verify", "lift"),
    ),
    StateSpec(
        "flip",
        "turn the mug upside down on the flip area and grasp it again",
        ("transit", "turn", "set_down", "release", "regrasp", "close", "verify", "lift"),
    ),
    StateSpec(
        "place",
        "carry the mug to its tray slot and let go",
        ("transit", "descend", "release", "retreat"),
    ),
    StateSpec("recover_lost_mug", "look for a mug that was not grasped or was dropped (§4.3.1)"),
    StateSpec("paused", "motion stopped on request; resume continues where it stopped"),
    StateSpec("fault", "a device failed; the arm is stopped; only reset leaves"),
    StateSpec(
        "estop", "emergency stop: the arm was stopped, then its torque switched off; only reset leaves"
    ),
    StateSpec("done", "the job ended: every planned mug is on the tray, or nothing more fits or remains"),
)

STATE_NAMES: Final = tuple(s.name for s in STATES)
LEAVES: Final = tuple(leaf for s in STATES for leaf in s.leaves)

# The states that do work for a loading job; pause, stop and resume apply to every leaf of these.
JOB_STATES: Final = ("detect", "plan", "side_grasp", "flip", "place", "recover_lost_mug")
JOB_LEAVES: Final = tuple(leaf for s in STATES if s.name in JOB_STATES for leaf in s.leaves)

# Leaf states in which the gripper should hold the mug; the force sensor is watched there.
CARRYING: Final = (
    "side_grasp.lift",
    "flip.transit",
    "flip.turn",
    "flip.set_down",
    "flip.lift",
    "place.transit",
    "place.descend",
)

# The phases a motion planner's ``Step.phase`` may name: the leaves of the three manipulation states.
CYCLE_PHASES: Final = tuple(
    leaf for s in STATES if s.name in ("side_grasp", "flip", "place") for leaf in s.leaves
)

GUARDS: Final[dict[str, str]] = {
    "needs_plan": "the mugs on the counter differ from the ones planned for (first look, a mug came or went)",
    "has_next_mug": "the plan still has a mug to take to the tray",
    "grasp_held": "the gripper closed on the mug: the pad force passed the threshold before the aperture "
    "got too small, and the force sensor says holding",
    "mug_found": "the lost mug was seen again on the counter and can be grasped where it lies",
}


def _chain(state: StateSpec, *, skip: tuple[str, ...] = ()) -> tuple[TransitionSpec, ...]:
    """``next`` steps through a state's substates in order (verify steps are left by ``verified``)."""
    leaves = state.leaves
    return tuple(TransitionSpec("next", (a,), b) for a, b in itertools.pairwise(leaves) if a not in skip)


def _state(name: str) -> StateSpec:
    return next(s for s in STATES if s.name == name)


_ALL_BUT_ESTOP: Final = tuple(n for n in STATE_NAMES if n != "estop")

TRANSITIONS: Final[tuple[TransitionSpec, ...]] = (
    TransitionSpec("start", ("idle", "done"), "detect"),
    TransitionSpec("detected", ("detect",), "plan", guard="needs_plan"),
    TransitionSpec("detected", ("detect",), "side_grasp", guard="has_next_mug"),
    TransitionSpec("detected", ("detect",), "done"),
    TransitionSpec("planned", ("plan",), "side_grasp", guard="has_next_mug"),
    TransitionSpec("planned", ("plan",), "done"),
    *_chain(_state("side_grasp"), skip=("side_grasp.verify",)),
    TransitionSpec("verified", ("side_grasp.verify",), "side_grasp.lift", guard="grasp_held"),
    TransitionSpec("verified", ("side_grasp.verify",), "recover_lost_mug", unless="grasp_held"),
    TransitionSpec("next", ("side_grasp.lift",), "flip"),
    *_chain(_state("flip"), skip=("flip.verify",)),
    TransitionSpec("verified", ("flip.verify",), "flip.lift", guard="grasp_held"),
    TransitionSpec("verified", ("flip.verify",), "recover_lost_mug", unless="grasp_held"),
    TransitionSpec("next", ("flip.lift",), "place"),
    *_chain(_state("place")),
    TransitionSpec("next", ("place.retreat",), "detect"),
    TransitionSpec("mug_dropped", CARRYING, "recover_lost_mug"),
    TransitionSpec("recovered", ("recover_lost_mug",), "side_grasp", guard="mug_found"),
    TransitionSpec("recovered", ("recover_lost_mug",), "plan"),
    TransitionSpec("pause", JOB_STATES, "paused"),
    TransitionSpec("resume", ("paused",), HISTORY),
    TransitionSpec("stop", (*JOB_STATES, "paused"), "idle"),
    TransitionSpec("fault", _ALL_BUT_ESTOP, "fault"),
    TransitionSpec("estop", STATE_NAMES, "estop"),
    TransitionSpec("reset", ("fault", "estop"), "idle"),
)

TRIGGERS: Final = tuple(dict.fromkeys(t.trigger for t in TRANSITIONS))

# Triggers a remote user may send as commands (the rest are fired by the job runner as work completes).
COMMAND_TRIGGERS: Final = ("start", "pause", "resume", "stop", "estop", "reset")


def guards_of(trigger: str) -> tuple[str, ...]:
    """The guard names the rows of one trigger consult (the keyword arguments firing it must carry)."""
    names: list[str] = []
    for t in TRANSITIONS:
        if t.trigger == trigger:
            names.extend(g for g in (t.guard, t.unless) if g is not None)
    return tuple(dict.fromkeys(names))


def triggers_from(leaf: str) -> tuple[str, ...]:
    """The events with a transition out of ``leaf`` (rows whose sources name it or its top-level state)."""
    sources = {leaf, top_level(leaf)}
    return tuple(dict.fromkeys(t.trigger for t in TRANSITIONS if sources & set(t.sources)))


def top_level(path: str) -> str:
    """``side_grasp.close`` → ``side_grasp``."""
    return path.split(SEPARATOR, 1)[0]
