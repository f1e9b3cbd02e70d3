"""Progress lines on stderr for long runs and benches: where the work is, how long it has taken, what is left.

One line per step, so a log or a CI job shows it as it goes and a pipe reads it line by line::

    dishbot run: mug 3 of 12 (m7), elapsed 41.2 s, simulated 182.4 s, about 80 s left
    bench placement: case 4 of 26 (dataset 1: sa, 5 runs), elapsed 12.3 s, about 68 s left

A ``Progress`` that is not ``enabled`` (``--json``, or a command that runs no finite job) prints nothing. The
lines go to stderr, never stdout, so the result a script reads is unchanged; a stderr that is closed (a
``| head`` that has exited) silences the progress rather than failing the work.
"""

from __future__ import annotations

import sys
from collections.abc import Callable
from typing import TextIO


class Progress:
    """Steps ``1..total`` of one piece of work, printed as ``<who>: <unit> k of N (<note>), elapsed ...``."""

    def __init__(
        self,
        who: str,
        total: int,
        *,
        unit: str = "case",
        enabled: bool = True,
        stream: TextIO | None = None,
        wall: Callable[[], float] | None = None,  # default: the one wall-clock seam, daemon.clock
    ) -> None:
        self.who = who
        self.total = total
        self.unit = unit
        self.enabled = enabled
        self._stream = stream
        if wall is None:
            from daemon.clock import wall_seconds  # here: the help screens stay free of NumPy

            wall = wall_seconds
        self._wall = wall
        self._started = wall()
        self._first_step: float | None = None  # the pace is measured from here, not from the set-up
        self._first_k = 1
        self._k = 0  # the step begun last
        self.lines: list[str] = []  # every line printed, for a summary or a test

    def step(self, k: int, note: str = "", *, simulated_s: float | None = None) -> None:
        """Say that step ``k`` (1-based) begins; ``simulated_s``: the simulated time since the start."""
        self._k = k
        if self._first_step is None:
            self._first_step, self._first_k = self._wall(), k
        self.say(f"{self.unit} {k} of {self.total}{f' ({note})' if note else ''}", k, simulated_s)

    def next(self, note: str = "", *, simulated_s: float | None = None) -> None:
        """Say that the step after the last one begins."""
        self._k += 1
        self.step(self._k, note, simulated_s=simulated_s)

    def done(self, note: str = "", *, simulated_s: float | None = None) -> None:
        """Say that the work is over (``note``: how it ended)."""
        self.say(f"done{f' ({note})' if note else ''}", None, simulated_s)

    def say(self, what: str, k: int | None, simulated_s: float | None) -> None:
        """Print ``<who>: <what>, elapsed ...``; with ``k``, the step begun, an estimate of the time left."""
        if not self.enabled:
            return
        now = self._wall()
        line = f"{self.who}: {what}, elapsed {now - self._started:.1f} s"
        if simulated_s is not None:
            line += f", simulated {simulated_s:.1f} s"
        if k is not None and self._first_step is not None and self._first_k < k <= self.total:
            pace = (now - self._first_step) / (k - self._first_k)  # wall seconds per step so far
            line += f", about {pace * (self.total - k + 1):.0f} s left"
        self.lines.append(line)
        stream = self._stream or sys.stderr
        try:
            stream.write(line + "\n")
            stream.flush()
        except (OSError, ValueError):  # stderr closed or gone: the work goes on without progress lines
            self.enabled = False
