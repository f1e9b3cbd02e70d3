"""What a job's events say happened: the mugs placed, the mugs given up and why, the faults.

The same fold serves ``dishbot record info`` (the events of a recording) and ``dishbot run --once`` (the
events as they are published), so both name each failed mug with the same reason. A mug given up because no
motion reached it carries the motion planner's last refusal for it ("the gripper would hit mug m9"); one
given up after failed grasps carries how the last attempt failed.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Final

from wire.messages import UNSET, BadMessage, Event, Payload, UnsetType, as_message

_DEVICE_FAULTS: Final = frozenset({"servo_fault", "bus_lost", "fsr_lost", "fsr_stale", "tray_collision"})
_MAX_DEVICE_FAULTS = 20


@dataclass(slots=True)
class JobOutcome:
    """The outcome of one job, folded from its ``events`` in order (``add``)."""

    placed: list[str] = field(default_factory=list)
    given_up: dict[str, str] = field(default_factory=dict)
    grasp_failures: dict[str, int] = field(default_factory=dict)
    drops: dict[str, int] = field(default_factory=dict)
    faults: list[str] = field(default_factory=list)
    device_faults: list[str] = field(default_factory=list)
    end_state: str | None = None
    _last_trouble: dict[str, str] = field(default_factory=dict)

    @classmethod
    def of(cls, events: Iterable[Event | Mapping[str, object]]) -> JobOutcome:
        outcome = cls()
        for event in events:
            outcome.add(event)
        return outcome

    def add(self, payload: Payload) -> None:
        """Fold one event in (a decoded one, or its payload; one that is not an event is left out); a
        ``start`` transition begins a new job (what came before is forgotten)."""
        try:
            event = as_message(payload, Event, name="events")
        except BadMessage:
            return
        kind = event.kind
        mug = _text(event.mug_id)
        if kind == "transition":
            if event.trigger == "start":
                self._reset()
            dest = event.dest
            if dest in ("done", "fault", "estop") or (dest == "idle" and event.trigger == "stop"):
                self.end_state = str(dest)
        elif kind == "mug_placed" and mug:
            self.placed.append(mug)
            self.given_up.pop(mug, None)
        elif kind == "mug_given_up" and mug:
            reason = _text(event.reason) or "no reason given"
            trouble = self._last_trouble.get(mug)
            self.given_up[mug] = f"{reason} ({trouble})" if trouble and trouble not in reason else reason
        elif kind == "motion_refused" and mug:
            self._last_trouble[mug] = f"last refusal: {_text(event.reason)}"
        elif kind == "grasp_failed" and mug:
            self.grasp_failures[mug] = self.grasp_failures.get(mug, 0) + 1
            self._last_trouble[mug] = f"last attempt: grasp failed in {_text(event.state) or '?'}"
        elif kind == "mug_dropped" and mug:
            self.drops[mug] = self.drops.get(mug, 0) + 1
            self._last_trouble[mug] = f"last attempt: dropped in {_text(event.state) or '?'}"
        elif kind == "fault":
            self.faults.append(_text(event.reason) or "no reason given")
        elif kind in _DEVICE_FAULTS and len(self.device_faults) < _MAX_DEVICE_FAULTS:
            where = _text(event.device) or _text(event.port)
            error = _text(event.error) or _text(event.b)
            self.device_faults.append(" ".join(p for p in (kind, where, error) if p))

    def failed_lines(self) -> list[str]:
        """One line per mug given up: ``m10: no motion reaches it (last refusal: ...)``."""
        return [f"{mug}: {reason}" for mug, reason in self.given_up.items()]

    def to_json(self) -> dict[str, object]:
        return {
            "end_state": self.end_state,
            "placed": list(self.placed),
            "given_up": [{"mug_id": m, "reason": r} for m, r in self.given_up.items()],
            "grasp_failures": dict(self.grasp_failures),
            "drops": dict(self.drops),
            "faults": list(self.faults),
            "device_faults": list(self.device_faults),
        }

    def _reset(self) -> None:
        self.placed.clear()
        self.given_up.clear()
        self.grasp_failures.clear()
        self.drops.clear()
        self.faults.clear()
        self.device_faults.clear()
        self.end_state = None
        self._last_trouble.clear()


def _text(value: str | UnsetType) -> str:
    return "" if value is UNSET else str(value)
