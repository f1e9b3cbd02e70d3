"""While a replay follows its recording, the stand-in's FSR simulator hands each sample to its reader at its
tick instead of sending its line (``replay.drivers.hand_force_samples``; issue 22: formatting, carrying and
parsing the lines was about a tenth of a kinematic replay's CPU, for a force the job is served from the
recording). The stand-in still closes its own grasps on that reader and still asks the world for its force
at every tick, so the reader must be exactly where the lines would have left it when the replay diverges
and the stand-in carries on alone."""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from pathlib import Path

import pytest

from daemon.backend import Backend
from daemon.sim_backend import KinematicCounter
from drivers.fsr.reader import FsrCounters
from drivers.interfaces import ForceReading
from drivers.sim.fsr import FsrSimulator
from replay import drivers as replay_drivers
from replay.drivers import Replayer
from replay.engine import ReplayOptions, replay
from replay.faults import FaultInjector, parse_faults
from replay.resim import Resimulation
from replay.session import RecordedSession

# A fault while the first mug is carried to the flip area: the reader holds it, its window full of force.
_FAULT = '[[fault]]\nkind = "fsr_spike"\nvalue_n = 30.0\nat_state = "flip.transit"\nafter_s = 0.5\n'
_PLAIN = (int, float, bool, str, bytes, bytearray, deque, list, ForceReading, FsrCounters, type(None))
# The simulator's tap and its counts of how its samples went out: what the hand-over changes, by design.
_DELIVERY = ("_tap", "lines_sent", "samples_tapped")


def _plain(obj: object, leave_out: tuple[str, ...] = ()) -> dict[str, object]:
    """Every field of ``obj`` that is data (not a task, a lock, a port or a callback), copied."""
    return {
        k: list(v) if isinstance(v, deque | bytearray | list) else v
        for k, v in vars(obj).items()
        if isinstance(v, _PLAIN) and k not in leave_out
    }


def _replayed(
    job: Path, monkeypatch: pytest.MonkeyPatch, hand: Callable[[Backend, Replayer], None]
) -> tuple[dict[str, object], FsrSimulator, dict[str, object]]:
    """Replay ``job`` with ``_FAULT``, the stand-in's FSR set up by ``hand``: its reader's and simulator's
    data as the replay diverged, the simulator, and the report (without its wall-clock parts)."""
    backends: list[Backend] = []
    at_divergence: dict[str, object] = {}

    def handing(backend: Backend, replayer: Replayer) -> None:
        backends.append(backend)
        hand(backend, replayer)

    take_over = Resimulation.take_over

    def taking_over(self: Resimulation, t_s: float) -> None:
        counter = backends[-1].counter
        assert isinstance(counter, KinematicCounter)
        at_divergence["reader"] = _plain(counter.cell.force)
        at_divergence["simulator"] = _plain(counter.cell.fsr_sim, _DELIVERY)
        take_over(self, t_s)

    monkeypatch.setattr(replay_drivers, "hand_force_samples", handing)
    monkeypatch.setattr(Resimulation, "take_over", taking_over)
    faults = FaultInjector(parse_faults(_FAULT, source="faults.toml"))
    report = replay(RecordedSession.load(job), ReplayOptions(), faults=faults).to_json()
    monkeypatch.undo()
    counter = backends[-1].counter
    assert isinstance(counter, KinematicCounter)
    return (
        at_divergence,
        counter.cell.fsr_sim,
        {k: v for k, v in report.items() if k not in ("wall_s", "speedup")},
    )


@pytest.mark.slow  # replays a one-mug job twice
def test_the_stand_ins_fsr_reader_is_where_its_lines_would_have_left_it_when_the_replay_diverges(
    one_mug_job: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    handed, handed_sim, handed_report = _replayed(one_mug_job, monkeypatch, replay_drivers.hand_force_samples)
    sent, sent_sim, sent_report = _replayed(one_mug_job, monkeypatch, lambda backend, replayer: None)
    # Handed over while the recording was served: no line went over the cable from the job's start to the
    # fault, about 7 s in (lines before it, for the reader's start; the rest after it).
    assert handed_sim.samples_tapped > 500
    assert sent_sim.samples_tapped == 0
    assert handed_sim.lines_sent + handed_sim.samples_tapped == sent_sim.lines_sent
    reader = handed["reader"]
    assert isinstance(reader, dict)
    assert reader["_holding"] is True
    assert isinstance(reader["counters"], FsrCounters)
    assert reader["counters"].samples > 500
    assert handed["reader"] == sent["reader"]
    assert handed["simulator"] == sent["simulator"]
    assert handed_report == sent_report
    assert handed_report["resimulated_from_s"] is not None
