"""On simulated time a simulated job is deterministic (issue 11): the same counter and seed give the same
sequence of states and events, with the same timestamps, however loaded the machine is.

Each run is the whole daemon (``serve``: the job, telemetry, a Zenoh session on loopback, the MCAP
recording) on a fresh simulated clock whose wall-clock start is pinned, so that even the published ``t``
must come out the same; what is compared is read back from the recordings.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from daemon.app import RunResult
from daemon.backend import Backend, SimOptions
from daemon.cell import open_backend
from daemon.clock import SimulatedClock
from daemon.config import load_config
from daemon.job import StartRequest
from recorder import HEADER_TOPIC, read_messages
from tests.fakes.counter import setup_mugs
from tests.fakes.daemon import serve_daemon

WALL_START = 1_795_000_000.0
ROBOT = "determinism"


def _run_once(tmp_path: Path, world: str, request: StartRequest) -> tuple[RunResult, Path]:
    config = load_config(overrides={"robot_id": ROBOT})
    clock = SimulatedClock(wall_start=WALL_START)

    async def main() -> RunResult:
        sim = SimOptions(world=world, dataset=1, seed=0)
        backend: Backend = await open_backend(config, sim=sim, clock=clock)
        return await serve_daemon(config, backend, tmp_path, once=request)

    result = clock.run(main())
    return result, result.recording


def _states_and_events(path: Path) -> list[tuple[str, int, dict[str, Any]]]:
    """Every ``state`` and ``events`` message as (topic, log time, payload)."""
    keep = (f"dishbot/{ROBOT}/state", f"dishbot/{ROBOT}/events")
    return [(m.topic, m.log_time_ns, m.payload) for m in read_messages(path, keep=keep.__contains__)]


def _placed_failed_given_up(messages: list[tuple[str, int, dict[str, Any]]]) -> dict[str, list[str]]:
    kinds = ("mug_placed", "grasp_failed", "mug_given_up")
    return {k: [str(p["mug_id"]) for _, _, p in messages if p.get("kind") == k] for k in kinds}


def _check_simulated_stamps(path: Path, messages: list[tuple[str, int, dict[str, Any]]]) -> None:
    """The session header records the simulated clock and its wall-clock start; every message is logged at
    the simulated ``t`` it carries."""
    read = read_messages(path, keep=lambda topic: topic == HEADER_TOPIC)
    assert read.header is not None
    assert read.header["clock"] == {"source": "simulated", "speed": "max", "wall_start": WALL_START}
    for _, log_time_ns, payload in messages:
        assert abs(float(payload["t"]) * 1e9 - log_time_ns) < 1e3


@pytest.mark.slow
def test_the_kinematic_cell_gives_the_same_states_and_events_twice(tmp_path: Path) -> None:
    # Three mugs (two small, one big): three cycles of planning, grasp, flip and place, with the telemetry
    # timers and device ticks interleaving them, visit every state and event kind the whole dataset-1 job
    # visits (its further cycles repeat the same kinds), in about a quarter of its time.
    request = StartRequest(mugs=setup_mugs(3))
    first, first_path = _run_once(tmp_path / "a", "kinematic", request)
    second, second_path = _run_once(tmp_path / "b", "kinematic", request)
    a, b = _states_and_events(first_path), _states_and_events(second_path)
    assert (first.end_state, first.summary.placed) == ("done", first.summary.planned - first.summary.failed)
    assert len(a) > 100
    assert a == b
    assert first.summary.duration_s == second.summary.duration_s
    _check_simulated_stamps(first_path, a)


@pytest.mark.slow
def test_the_mujoco_cell_gives_the_same_states_and_the_same_mugs_placed_failed_and_given_up_twice(
    tmp_path: Path,
) -> None:
    request = StartRequest(mugs=setup_mugs(2))
    first, first_path = _run_once(tmp_path / "a", "mujoco", request)
    second, second_path = _run_once(tmp_path / "b", "mujoco", request)
    a, b = _states_and_events(first_path), _states_and_events(second_path)
    assert first.end_state == "done"
    states = [(log_time, p["state"]) for topic, log_time, p in a if topic.endswith("/state")]
    assert states == [(log_time, p["state"]) for topic, log_time, p in b if topic.endswith("/state")]
    assert _placed_failed_given_up(a) == _placed_failed_given_up(b)
    assert len(_placed_failed_given_up(a)["mug_placed"]) == first.summary.placed == second.summary.placed >= 1
    assert a == b  # and, in fact, every event with its detail and its simulated time
    _check_simulated_stamps(first_path, a)
