"""What the ``dishbot`` pytest fixture hands a test (``replay.pytest_plugin``): record a simulated session,
replay it with faults, look at what happened. Imported when a test first uses the fixture, not when pytest
loads the plugin.
"""

from __future__ import annotations

import json
from collections.abc import Collection, Mapping, Sequence
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Any

import pytest

from recorder import RecordingRead, read_messages
from replay.engine import Faults, ReplayOptions, ReplayReport, fault_text, replay
from replay.faults import FaultOutcome
from replay.session import Divergence, RecordedSession, TraceEvent


@dataclass(frozen=True)
class ReplayTrace:
    """What a replay did: the report and the replay's own recording (its file; read when first looked at,
    only counted for ``topics``)."""

    report: ReplayReport
    path: Path

    @cached_property
    def recording(self) -> RecordingRead:
        """The replay's own recording, every message decoded."""
        return read_messages(self.path)

    @property
    def match(self) -> bool:
        return self.report.match

    @property
    def states(self) -> list[str]:
        """Every state entered, in order."""
        return list(self.report.replayed.states)

    @property
    def final_state(self) -> str:
        return self.report.replayed.final_state

    @property
    def first_divergence(self) -> Divergence | None:
        return self.report.first_divergence

    @property
    def faults(self) -> list[dict[str, object]]:
        """The faults fired: ``kind``, ``fired_at_s`` and the target."""
        return [dict(f) for f in self.report.faults]

    @property
    def resimulated_from_s(self) -> float | None:
        """From when (seconds from the job's start) the replay went on in the re-simulated world."""
        return self.report.resimulated_from_s

    @property
    def fault_outcomes(self) -> list[FaultOutcome]:
        """Every fault of the file: fired (when, ended when) or not, and why not."""
        return list(self.report.fault_outcomes)

    @property
    def unfired(self) -> list[FaultOutcome]:
        """The faults of the file that did not happen."""
        return list(self.report.unfired)

    @property
    def events_by_kind(self) -> dict[str, list[TraceEvent]]:
        return self.report.replayed.events_by_kind()

    def events(self, kind: str | None = None) -> list[TraceEvent]:
        return [e for e in self.report.replayed.events if kind is None or e.kind == kind]

    def topics(self) -> dict[str, int]:
        """Messages per topic in the replay's recording."""
        return dict(read_messages(self.path, keep=_nothing).topic_counts)


class DishbotReplay:
    """The ``dishbot`` fixture: see the module's docstring."""

    def __init__(self, directory: Path, cache: dict[str, Path]) -> None:
        self._dir = directory
        self._cache = cache
        self._n = 0

    def record(
        self,
        *,
        world: str = "kinematic",
        dataset: int = 1,
        seed: int = 0,
        mugs: Sequence[tuple[str, str, float, float]] | None = None,
        overrides: Mapping[str, Any] | None = None,
    ) -> Path:
        """A recording of one simulated job (kept for the test session: the same arguments, the same file)."""
        from replay.record import record_job

        key = json.dumps([world, dataset, seed, mugs, overrides], sort_keys=True, default=str)
        if key not in self._cache:
            directory = self._dir / f"recorded-{len(self._cache)}"
            job = record_job(
                directory, world=world, dataset=dataset, seed=seed, mugs=mugs, overrides=overrides
            )
            self._cache[key] = job.path
        return self._cache[key]

    def load(self, path: Path | str) -> RecordedSession:
        return RecordedSession.load(Path(path))

    def replay(
        self,
        session: Path | str | RecordedSession,
        *,
        faults: Faults | None = None,
        speed: float | None = None,
        may_not_fire: bool | Collection[int] = False,
        resim: str | None = None,
    ) -> ReplayTrace:
        """Replay ``session`` with ``faults`` (a fault file, TOML text or a list of ``[[fault]]`` tables).

        A fault that did not fire fails the test (it would pass without testing what it says), unless the
        test says it may not: ``may_not_fire=True`` for any, or the faults' places in the file (1-based).
        ``resim`` picks the stand-in world after a divergence (``kinematic``, ``mujoco``; default: the
        recording's own simulated world, kinematic for a robot's recording)."""
        recorded = session if isinstance(session, RecordedSession) else self.load(session)
        self._n += 1
        out = self._dir / f"replay-{self._n}.mcap"
        injector = None
        if faults is not None:
            from replay.faults import FaultInjector, parse_faults

            injector = FaultInjector(
                parse_faults(fault_text(faults), source="faults", config=recorded.config)
            )
        report = replay(recorded, ReplayOptions(speed=speed, record=out, resim=resim), faults=injector)
        allowed = may_not_fire if not isinstance(may_not_fire, bool) else ()
        missed = [o for o in report.unfired if may_not_fire is not True and o.index not in allowed]
        if missed:
            pytest.fail(
                "; ".join(o.line() for o in missed)
                + " (pass may_not_fire=True, or the faults' indices, if that is expected)",
                pytrace=False,
            )
        return ReplayTrace(report, out)


def _nothing(_topic: str) -> bool:
    """Decode no message: only count them."""
    return False
