"""The fault matrix (issue 13, docs/faults.md) through replays: one recorded job on the kinematic cell,
replayed with each row's faults injected at the device boundary or in the simulated world. Each row checks
the state the daemon ends in, the events it published and what the replay's recording holds.

Rows that need the real drivers (the servo chain's error bits, polling, a lost adapter, corrupt replies),
a process to kill or a Zenoh client live with the drivers' and the daemon's own tests; docs/faults.md says
which test holds each row.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import pytest

from replay.harness import DishbotReplay, ReplayTrace
from tests.replay.conftest import THREE_MUGS


@dataclass(frozen=True)
class Row:
    """One row of the matrix: the faults, the state the job must end in, events it must publish (kinds, or
    ``kind:text`` where the fault's reason must contain ``text``) and topics the recording must hold."""

    name: str
    faults: Sequence[Mapping[str, object]]
    end: str
    events: Sequence[str] = ()
    recorded: Sequence[str] = ("events", "state", "input/joints")
    not_events: Sequence[str] = field(default_factory=tuple)


ROWS = (
    Row(
        "1 overload mid-flip",
        [{"kind": "servo_overload", "servo": 3, "at_state": "flip.turn", "after_s": 0.2}],
        "fault",
        ("fault_injected", "fault:ServoFault"),
    ),
    Row(
        "4 servo silent for good",
        [{"kind": "servo_silent", "servo": 4, "at_state": "flip.transit"}],
        "fault",
        ("fault_injected", "fault:servo(s) 4 did not answer"),
    ),
    Row(
        "7 fsr drop in lift",
        [{"kind": "fsr_drop", "at_state": "side_grasp.lift", "after_s": 0.1, "duration_s": 0.5}],
        "done",
        ("fault_injected", "mug_dropped"),
    ),
    Row(
        "7 fsr drop in transit",
        [{"kind": "fsr_drop", "at_state": "flip.transit", "after_s": 0.1, "duration_s": 0.5}],
        "done",
        ("fault_injected", "mug_dropped"),
    ),
    Row(
        "7 fsr drop in turn",
        [{"kind": "fsr_drop", "at_state": "flip.turn", "after_s": 0.1, "duration_s": 0.5}],
        "done",
        ("fault_injected", "mug_dropped"),
    ),
    Row(
        "7 fsr drop in set-down",
        [{"kind": "fsr_drop", "at_state": "flip.set_down", "after_s": 0.1, "duration_s": 0.5}],
        "done",
        ("fault_injected", "mug_dropped"),
    ),
    Row(
        "7 fsr drop in descend",
        [{"kind": "fsr_drop", "at_state": "place.descend", "after_s": 0.1, "duration_s": 0.5}],
        "done",
        ("fault_injected", "mug_dropped"),
    ),
    Row(
        "8 one-sample fsr spike",
        [{"kind": "fsr_spike", "at_state": "place.transit", "after_s": 0.1}],
        "done",
        ("fault_injected",),
        not_events=("mug_dropped",),
    ),
    Row(
        "20 a mug slips out of the gripper",
        [{"kind": "mug_slip", "at_state": "flip.transit", "after_s": 0.3}],
        "done",
        ("fault_injected", "mug_dropped"),
    ),
    Row(
        "21 a counter mug moved meanwhile",
        [{"kind": "mug_moved", "at_state": "side_grasp.lift", "dx_m": 0.03, "dy_m": 0.0}],
        "done",
        ("fault_injected",),
    ),
)


# The camera rows run on the MuJoCo cell: its rendered depth camera behind the real observer and detector,
# with the frame timeout, age limit and retries of [camera].
CAMERA_ROWS = (
    Row(
        "9 camera without a frame for a moment",
        [{"kind": "camera_no_frame", "at_state": "detect", "duration_s": 0.5}],
        "done",
        ("fault_injected",),
        not_events=("fault",),
    ),
    Row(
        "9 camera without a frame for good",
        [{"kind": "camera_no_frame", "at_state": "detect", "occurrence": 2}],
        "fault",
        ("fault_injected", "fault:camera: the RealSense camera sent no frame"),
    ),
    Row(
        "9 camera stale",
        [{"kind": "camera_stale", "at_state": "detect", "occurrence": 2}],
        "fault",
        ("fault_injected", "fault:old"),
    ),
    Row(
        "9 camera bad frame",
        [{"kind": "camera_bad_frame", "at_state": "detect"}],
        "fault",
        ("fault_injected", "fault:camera: bad frame"),
    ),
    Row(
        "9 camera hung",
        [{"kind": "camera_hang", "at_state": "detect", "occurrence": 2}],
        "fault",
        ("fault_injected", "fault:camera: no frame within"),
    ),
)
TWO_MUGS = THREE_MUGS[:2]


@pytest.fixture(scope="module")
def recorded_job(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return DishbotReplay(tmp_path_factory.mktemp("matrix"), {}).record(world="kinematic", mugs=THREE_MUGS)


@pytest.fixture(scope="module")
def recorded_mujoco_job(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return DishbotReplay(tmp_path_factory.mktemp("matrix-mujoco"), {}).record(world="mujoco", mugs=TWO_MUGS)


def _check(row: Row, trace: ReplayTrace) -> None:
    assert trace.faults, f"{row.name}: the fault never fired"
    assert trace.final_state == row.end, (
        row.name,
        trace.states[-5:],
        [e.to_json() for e in trace.events("fault")],
    )
    kinds = trace.events_by_kind
    for wanted in row.events:
        kind, _, text = wanted.partition(":")
        assert kind in kinds, f"{row.name}: no {kind} event ({sorted(kinds)})"
        if text:
            reasons = [str(e.detail.get("reason", "")) for e in kinds[kind]]
            assert any(text in r for r in reasons), (row.name, reasons)
    for unwanted in row.not_events:
        assert unwanted not in kinds, f"{row.name}: {unwanted} {kinds[unwanted]}"
    topics = {t.split("/", 2)[-1] for t in trace.topics()}
    assert set(row.recorded) <= topics
    # The recording holds the injected fault where the daemon met it.
    assert "fault_injected" in kinds


@pytest.mark.parametrize("row", ROWS, ids=[r.name for r in ROWS])
@pytest.mark.slow
def test_each_row_of_the_matrix_ends_in_its_safe_state(
    row: Row, recorded_job: Path, dishbot: DishbotReplay
) -> None:
    trace = dishbot.replay(recorded_job, faults=row.faults)
    _check(row, trace)


@pytest.mark.parametrize("row", CAMERA_ROWS, ids=[r.name for r in CAMERA_ROWS])
@pytest.mark.slow
def test_each_camera_row_ends_in_its_safe_state(
    row: Row, recorded_mujoco_job: Path, dishbot: DishbotReplay
) -> None:
    trace = dishbot.replay(recorded_mujoco_job, faults=row.faults)
    _check(row, trace)


@pytest.mark.slow
def test_a_replay_without_faults_of_the_matrix_job_matches(
    recorded_job: Path, dishbot: DishbotReplay
) -> None:
    trace = dishbot.replay(recorded_job)
    assert trace.match
    assert trace.final_state == "done"
