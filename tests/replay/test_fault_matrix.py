"""The fault matrix (issue 13, docs/faults.md) on both simulated cells.

``test_each_fault_kind_ends_alike_on_both_cells`` runs the same fault file for every device and world fault
kind on the kinematic and on the MuJoCo cell (one daemon each, a one-mug job; the MuJoCo side is slow): both
cells put the same device simulators behind the same drivers, so both must end in the state docs/faults.md
gives and publish the same key events. The replay rows run a recorded one-mug job again with each row's
faults (a two-mug job for the row that moves a counter mug meanwhile: it needs a mug the arm does not hold)
and check the state the daemon ends in, the events it published and what the replay's recording holds.

The camera faults that end a job, and the short gap without a frame, are compared on both cells by the
camera rows alone (``test_each_camera_row_ends_in_its_safe_state``: replayed on each cell, the daemon meets
the fault in a simulated cell of that world and must end in the state, with the reason, docs/faults.md
gives); running the same files live on both cells as well cost about a fifth of the module. Live,
``test_faults_kinematic`` runs every camera fault on the kinematic cell and ``test_faults_mujoco`` the
missing and the bad frame on the MuJoCo cell; the hang bridged by a retry stays a live row of both cells.

Rows that need a process to kill, a disk or a Zenoh client live with the daemon's own tests; docs/faults.md
says which test holds each row.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import pytest

from replay.harness import DishbotReplay, ReplayTrace
from tests.replay.conftest import THREE_MUGS
from tests.replay.faulty import FaultRun, run_with_faults


@dataclass(frozen=True)
class Row:
    """One row of the matrix: the faults, the state the job must end in, events it must publish (kinds, or
    ``kind:text`` where the fault's reason must contain ``text``), topics the recording must hold and how
    many mugs the replayed job has."""

    name: str
    faults: Sequence[Mapping[str, object]]
    end: str
    events: Sequence[str] = ()
    recorded: Sequence[str] = ("events", "state", "input/joints")
    not_events: Sequence[str] = field(default_factory=tuple)
    mugs: int = 1


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
        mugs=2,
    ),
)


# The camera rows run on both cells: the camera fault model behind the real observer's frame checks (the
# frame timeout, age limit and retries of [camera]), before the rendered depth detector (MuJoCo) or the truth
# detector (kinematic).
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
        ("fault_injected", "fault:camera: the RealSense camera sent no frame within 1.0 s"),
    ),
    Row(
        "9 camera stale",
        [{"kind": "camera_stale", "at_state": "detect", "occurrence": 2}],
        "fault",
        ("fault_injected", "fault: s old"),
    ),
    Row(
        "9 camera bad frame",
        [{"kind": "camera_bad_frame", "at_state": "detect"}],
        "fault",
        ("fault_injected", "fault:camera: bad frame (NaN depth)"),
    ),
    Row(
        "9 camera hung",
        [{"kind": "camera_hang", "at_state": "detect", "occurrence": 2}],
        "fault",
        ("fault_injected", "fault:camera: no frame within 2.0 s"),
    ),
)


@pytest.fixture(scope="module")
def recorded_jobs(one_mug_job: Path, two_mug_job: Path) -> Mapping[int, Path]:
    """The kinematic cell's one- and two-mug jobs by their number of mugs, each recorded once for the test
    session (``tests/replay/conftest.py``); module-scoped so that the rows replaying them run on one worker
    (``tests/conftest.py``) and they are recorded once, not on every worker. The rows fire their faults on
    the first mug: a second mug would only add a cycle to the replays of all but the row that moves it.
    Without faults both replay to a match, so what a row's replay does otherwise is its faults' doing: the
    two-mug job in ``test_replay_engine::test_a_kinematic_job_replays_exactly_from_its_recording``, the
    one-mug job twenty times in ``test_replay_faithful::test_twenty_replays_of_one_recording_...`` (this
    module replayed each once more to see it)."""
    return {1: one_mug_job, 2: two_mug_job}


@pytest.fixture(scope="module")
def recorded_mujoco_job(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The MuJoCo cell's one-mug job (the camera rows'), recorded once for the module."""
    directory = tmp_path_factory.mktemp("matrix-mujoco")
    return DishbotReplay(directory, {}).record(world="mujoco", mugs=THREE_MUGS[:1])


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
    row: Row, recorded_jobs: Mapping[int, Path], dishbot: DishbotReplay
) -> None:
    trace = dishbot.replay(recorded_jobs[row.mugs], faults=row.faults)
    _check(row, trace)


@pytest.mark.parametrize("world", ["kinematic", "mujoco"])
@pytest.mark.parametrize("row", CAMERA_ROWS, ids=[r.name for r in CAMERA_ROWS])
@pytest.mark.slow
def test_each_camera_row_ends_in_its_safe_state(
    row: Row, world: str, recorded_jobs: Mapping[int, Path], recorded_mujoco_job: Path, dishbot: DishbotReplay
) -> None:
    # Both recordings named as fixtures (not looked up by name): the rows join the module's group, which
    # records each once (tests/conftest.py groups the tests whose fixtures are module-scoped).
    job = recorded_jobs[row.mugs] if world == "kinematic" else recorded_mujoco_job
    trace = dishbot.replay(job, faults=row.faults)
    _check(row, trace)


@dataclass(frozen=True)
class Kind:
    """One fault file run on both cells: the state the job must end in, events it must publish (kinds, or
    ``kind:text`` where one such event's ``reason`` must contain ``text``) and events it must not."""

    name: str
    text: str
    end: str
    events: Sequence[str] = ()
    not_events: Sequence[str] = ()
    mugs: int = 1


def _file(**fault: object) -> str:
    fields = "".join(f"{k} = {v!r}\n".replace("'", '"') for k, v in fault.items())
    return f"[[fault]]\n{fields}"


BOTH_CELLS = (
    Kind(
        "1 arm servo overload in the turn",
        _file(kind="servo_overload", servo=3, at_state="flip.turn", after_s=0.2),
        "fault",
        ("servo_fault", "fault:ServoFault: servo 3 on inprocess:ttyDXL reports overload"),
    ),
    Kind(
        "1 gripper overload while closing, recovered",
        _file(kind="servo_overload", servo=6, at_state="side_grasp.close", after_s=0.1),
        "done",
        ("gripper_overload_recovered",),
        ("fault",),
    ),
    Kind(
        "2 servo overheats",
        _file(kind="servo_overheat", servo=2, at_state="side_grasp.lift"),
        "fault",
        ("servo_fault", "fault:overheating"),
    ),
    Kind(
        "2 servo supply sags",
        _file(kind="servo_voltage", servo=4, at_state="side_grasp.lift"),
        "fault",
        ("servo_fault", "fault:voltage"),
    ),
    Kind(
        "4 servo silent once (10 ms), bridged by the retries",
        _file(kind="servo_silent", servo=4, at_state="flip.transit", duration_s=0.01),
        "done",
        (),
        ("servo_fault", "fault"),
    ),
    Kind(
        "4 servo silent for good",
        _file(kind="servo_silent", servo=4, at_state="flip.transit"),
        "fault",
        ("servo_fault", "fault:BusTimeout: servo(s) 4 did not answer"),
    ),
    Kind(
        "5 corrupt packets under the limit (5 %)",
        _file(kind="bus_corrupt", rate=0.05, seed=3, at_state="side_grasp.approach", duration_s=5.0),
        "done",
        (),
        ("fault",),
    ),
    Kind(
        "5 corrupt packets over the limit (100 %)",
        _file(kind="bus_corrupt", rate=1.0, at_state="side_grasp.approach"),
        "fault",
        ("fault:BusCorrupt: servo(s) ",),
    ),
    Kind(
        "3 servo bus unplugged mid-job",
        _file(kind="bus_unplug", at_state="flip.transit", duration_s=1.0),
        "fault",
        ("bus_lost", "fault:bus_lost on inprocess:ttyDXL"),
    ),
    Kind(
        "7 FSR adapter unplugged for a moment while carrying",
        _file(kind="bus_unplug", device="fsr", at_state="flip.transit", duration_s=0.1),
        "done",
        ("fsr_lost", "fsr_restored"),
        ("fault",),
    ),
    Kind(
        "7 FSR reads no force while carrying",
        _file(kind="fsr_drop", at_state="flip.transit", after_s=0.1, duration_s=0.5),
        "done",
        ("mug_dropped",),
        ("fault",),
    ),
    Kind(
        "8 one-sample FSR spike",
        _file(kind="fsr_spike", value_n=30.0, at_state="place.transit"),
        "done",
        (),
        ("mug_dropped", "fault"),
    ),
    Kind(
        "7 FSR silent while carrying",
        _file(kind="fsr_silent", at_state="flip.transit"),
        "fault",
        ("fsr_stale", "fault:fsr_stale on inprocess:ttyFSR"),
    ),
    Kind(
        "9 camera hung for a moment (bridged)",
        _file(kind="camera_hang", at_state="detect", duration_s=3.0),
        "done",
        (),
        ("fault",),
    ),
    Kind(
        "20 the carried mug slips out",
        _file(kind="mug_slip", at_state="flip.transit", after_s=0.3),
        "done",
        ("mug_dropped",),
        ("fault",),
    ),
    Kind(
        "21 a counter mug moved meanwhile",
        _file(kind="mug_moved", at_state="side_grasp.lift", dx_m=0.03, dy_m=0.0),
        "done",
        (),
        ("fault",),
        mugs=2,
    ),
)


def outcome(run: FaultRun) -> tuple[str, tuple[str, ...], str]:
    """The end state, the key events (device, job and fault events, in order, each kind once) and the fault's
    reason of one run: what must be the same on both cells."""
    key = (
        "servo_fault",
        "servo_warning",
        "gripper_overload_recovered",
        "bus_lost",
        "bus_restored",
        "fsr_lost",
        "fsr_stale",
        "fsr_restored",
        "mug_dropped",
        "mug_found",
        "mug_given_up",
        "fault",
    )
    kinds = tuple(dict.fromkeys(k for k in run.kinds() if k in key))
    faults = run.events("fault")
    return run.result.end_state, kinds, str(faults[0]["reason"]) if faults else ""


@pytest.mark.parametrize("world", ["kinematic", "mujoco"])
@pytest.mark.parametrize("kind", BOTH_CELLS, ids=[k.name for k in BOTH_CELLS])
@pytest.mark.slow
def test_each_fault_kind_ends_alike_on_both_cells(kind: Kind, world: str, tmp_path: Path) -> None:
    run = run_with_faults(tmp_path, kind.text, world=world, mugs=kind.mugs)
    assert [o.fired for o in run.injector.outcomes()] == [True], run.injector.outcomes()
    end, kinds, reason = outcome(run)
    assert end == kind.end, (world, kind.name, kinds, reason)
    for wanted in kind.events:
        name, _, text = wanted.partition(":")
        assert name in kinds, (world, kind.name, kinds)
        if text:
            assert text in reason, (world, kind.name, reason)
    for unwanted in kind.not_events:
        assert unwanted not in kinds, (world, kind.name, kinds, reason)
