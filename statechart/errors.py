"""Exceptions of the statechart."""

from __future__ import annotations


class EventRefused(ValueError):
    """The event is not allowed in the current state (or no guard let it through); the chart did not move."""

    def __init__(self, trigger: str, state: str) -> None:
        super().__init__(f"cannot {trigger} in state {state}")
        self.trigger = trigger
        self.state = state
