"""Any job file replays faithfully: jobs recorded here (real daemons on the simulated kinematic cell, seeded)
that an operator paused and resumed, that a Zenoh ``start`` began, that ended in a servo overload or a bus
unplug, replay to a match (``--check``); their commands come where they fell in the job, their device
events and read failures at the same call, their motion plans from the recording; and a replay is the same
every time."""

from __future__ import annotations

import asyncio
import json
import threading
from collections.abc import Callable, Mapping
from pathlib import Path

import pytest

from cli.main import main
from daemon.app import RunResult, ServeContext, ServeHooks
from daemon.backend import SimOptions
from daemon.cell import open_backend
from daemon.clock import SimulatedClock
from drivers.dynamixel.bus import BusTimeout
from drivers.dynamixel.health import ServoHealthFault
from drivers.errors import BusLost, ServoFault
from perception.errors import CameraFault
from recorder import read_messages
from recorder.files import is_job_file
from replay.drivers import recorded_failure
from replay.engine import ReplayOptions, ReplayReport, replay
from replay.record import record_job
from replay.session import RecordedSession
from tests.fakes.daemon import loopback, serve_daemon
from tests.replay.conftest import copy_recording
from tests.replay.faulty import counter_mugs, robot_config, run_with_faults
from wire.messages import Failure, convert

OVERLOAD = '[[fault]]\nkind = "servo_overload"\nservo = 3\nat_state = "flip.turn"\n'
UNPLUG = '[[fault]]\nkind = "bus_unplug"\nat_state = "flip.transit"\nduration_s = 5\n'


def _job_file(files: tuple[Path, ...]) -> Path:
    jobs = [p for p in files if is_job_file(p)]
    assert len(jobs) == 1, files
    return jobs[0]


def _faulted_job(tmp_path: Path, text: str, world: str = "kinematic") -> Path:
    run = run_with_faults(tmp_path, text, mugs=1, world=world)
    assert run.states[-1] == "fault"
    return _job_file(run.result.files)


def _ended(events: list[dict[str, object]]) -> bool:
    return any(e.get("kind") == "transition" and e.get("dest") in ("done", "fault") for e in events)


def _daemon_job(
    tmp_path: Path, operator: Callable[[ServeContext, str], None], *, speed: float | None = None
) -> Path:
    """A daemon (no ``--once``) on the kinematic cell, listening on Zenoh; ``operator(ctx, endpoint)``
    starts the job its own way once the daemon is ready; stopped once the job has ended (or after a
    simulated hour). ``speed``: the simulated clock's pace (a job started from another thread, over
    Zenoh, should not find the idle daemon simulated hours ahead)."""
    config = robot_config()
    endpoint = loopback()
    clock = SimulatedClock(speed=speed)
    ended: list[dict[str, object]] = []

    def tap(topic: str, payload: Mapping[str, object]) -> None:
        if topic == "events":
            ended.append(dict(payload))

    def ready(ctx: ServeContext) -> None:
        operator(ctx, endpoint)

        async def stop_once_ended() -> None:
            for _ in range(7200):
                if _ended(ended):
                    break
                await ctx.clock.sleep(0.5)
            await ctx.clock.sleep(ctx.config.recording.job_tail_s)
            ctx.stop.set()

        asyncio.get_running_loop().create_task(stop_once_ended())

    async def run() -> RunResult:
        backend = await open_backend(config, sim=SimOptions(world="kinematic", seed=0), clock=clock)
        return await serve_daemon(
            config, backend, tmp_path / "rec", listen=(endpoint,), on_publish=(tap,), on_ready=ready
        )

    result = clock.run(run())
    return _job_file(result.files)


def _start_body(mugs: int) -> bytes:
    mugs_json = [
        {"id": m.mug_id, "type": m.type, "x_m": m.x_m, "y_m": m.y_m}
        for m in counter_mugs(robot_config(), mugs)
    ]
    return json.dumps({"mugs": mugs_json}).encode()


def _check(job: Path) -> ReplayReport:
    report = replay(RecordedSession.load(job))
    assert report.match, report.first_divergence
    assert report.overran_s is None
    assert report.replayed.final_state == report.recorded.final_state
    assert report.replayed.states == report.recorded.states
    return report


def _check_cli(job: Path, capsys: pytest.CaptureFixture[str]) -> None:
    capsys.readouterr()
    assert main(["--log-level", "warning", "replay", str(job), "--check", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["match"] is True
    assert doc["overran_s"] is None


@pytest.mark.slow
@pytest.mark.parametrize("world", ["kinematic", "mujoco"])
@pytest.mark.parametrize(("text", "event"), [(OVERLOAD, "servo_fault"), (UNPLUG, "bus_lost")])
def test_a_job_that_ended_in_a_device_fault_replays_to_a_match(
    text: str, event: str, world: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The device event comes at the same call, the failing call fails with the same error at the same
    moment, so the job faults as it did (not 0.5-1.2 s late, after the cell's own move). On the MuJoCo
    cell the fault is the real drivers' (over the device simulators)."""
    job = _faulted_job(tmp_path, text, world)
    session = RecordedSession.load(job)
    assert [r.payload["kind"] for r in session.device_events] == [event]
    report = _check(job)
    assert report.replayed.state_times_s == pytest.approx(report.recorded.state_times_s, abs=1e-6)
    faults = [e for e in report.replayed.events if e.kind == "fault"]
    recorded = [e for e in report.recorded.events if e.kind == "fault"]
    assert [f.detail["reason"] for f in faults] == [f.detail["reason"] for f in recorded]
    assert report.served["device_event"] == 1
    _check_cli(job, capsys)


@pytest.mark.slow
def test_a_device_fault_recording_of_the_older_format_replays_to_a_match(tmp_path: Path) -> None:
    """A recording without the new inputs (device events as such, read failures, motion plans, the
    commands' and events' places, the errors' classes), as main's recorder wrote it: its device events
    are taken from ``events`` and placed by time, and it matches all the same."""
    job = _faulted_job(tmp_path, OVERLOAD)
    new_topics = (
        "input/device_event",
        "input/motion",
        "input/gripper",
        "input/gripper_failed",
        "input/joints_failed",
        "input/health_failed",
    )

    def older(topic: str, payload: dict[str, object]) -> dict[str, object] | None:
        if topic in new_topics:
            return None
        return {k: v for k, v in payload.items() if not k.startswith(("at_", "error_"))}

    old = copy_recording(job, tmp_path / "old-job.mcap", older)
    session = RecordedSession.load(old)
    assert not any(k.startswith("input/device") or k == "input/motion" for k in session.streams)
    assert [r.payload["kind"] for r in session.device_events] == ["servo_fault"]
    report = _check(old)
    assert "motion" not in report.served  # planned again, as before


@pytest.mark.slow
def test_a_job_started_over_zenoh_is_started_once_and_replays_to_a_match(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The ``start`` query is logged after the start transition (its reply comes after it): the replay
    starts the job with it, once."""
    body = _start_body(1)
    answers: list[str] = []

    def over_zenoh(ctx: ServeContext, endpoint: str) -> None:
        import zenoh

        from daemon.zenoh_session import session_config

        def send() -> None:
            with zenoh.open(session_config(listen=[], connect=[endpoint])) as z:
                for reply in z.get(f"dishbot/{ctx.config.robot_id}/cmd/start", payload=body, timeout=30.0):
                    answers.append(reply.ok.payload.to_string() if reply.ok is not None else "no answer")

        threading.Thread(target=send, daemon=True).start()

    job = _daemon_job(tmp_path, over_zenoh, speed=20.0)
    assert len(answers) == 1
    assert json.loads(answers[0])["ok"] is True
    session = RecordedSession.load(job)
    starting = session.starting_command()
    assert starting is not None
    assert starting.t_ns >= session.start_ns
    assert session.later_commands() == []
    report = _check(job)
    assert report.replayed.states.count("detect") == report.recorded.states.count("detect")
    triggers = [e.detail.get("trigger") for e in report.replayed.events if e.kind == "transition"]
    assert triggers.count("start") == 1
    _check_cli(job, capsys)


def _paused_and_resumed(tmp_path: Path, *, pause_in: str = "flip.transit", paused_s: float = 2.0) -> Path:
    body = _start_body(1)

    def operator(ctx: ServeContext, _endpoint: str) -> None:
        async def go() -> None:
            assert (await ctx.handle("start", body, False))["ok"]
            while ctx.job.chart.state != pause_in:
                await ctx.clock.sleep(0.01)
            await ctx.clock.sleep(0.3)
            assert (await ctx.handle("pause", b"", False))["ok"]
            await ctx.clock.sleep(paused_s)
            assert (await ctx.handle("resume", b"", False))["ok"]

        asyncio.get_running_loop().create_task(go())

    return _daemon_job(tmp_path, operator)


@pytest.mark.slow
def test_a_paused_and_resumed_job_replays_to_a_match(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    job = _paused_and_resumed(tmp_path)
    session = RecordedSession.load(job)
    assert [str(c.payload["verb"]) for c in session.later_commands()] == ["pause", "resume"]
    assert "paused" in session.trace.states
    report = _check(job)
    assert report.replayed.final_state == "done"
    # Each command came where it fell: the pause 0.3 s into the transit, the resume 2 s later.
    paused = report.replayed.states.index("paused")
    assert report.replayed.state_times_s[paused] == pytest.approx(
        session.trace.state_times_s[paused], abs=1e-6
    )
    _check_cli(job, capsys)


@pytest.mark.slow
def test_a_replay_that_runs_past_its_limit_says_so(tmp_path: Path) -> None:
    """The resume left out of the recording: the replay's job stays paused; the report says it ran past
    its limit (and the trace does not match), rather than ending quietly in ``paused``. The limit is 30 s
    past the recorded job's end, not the default 600 s: the paused daemon idled through the rest, about
    three fifths of the test's time, for the same report."""
    job = _paused_and_resumed(tmp_path, paused_s=1.0)

    def no_resume(topic: str, payload: dict[str, object]) -> dict[str, object] | None:
        return None if topic == "input/command" and payload.get("verb") == "resume" else payload

    changed = copy_recording(job, tmp_path / "no-resume-job.mcap", no_resume)
    session = RecordedSession.load(changed)
    report = replay(session, ReplayOptions(overrun_s=30.0))
    assert report.overran_s == pytest.approx(session.trace.duration_s + 30.0)
    assert report.replayed.final_state == "paused"
    assert not report.match
    assert any("ran past its limit" in line for line in report.lines())
    assert report.to_json()["overran_s"] == report.overran_s


@pytest.mark.slow
def test_motion_plans_are_served_from_the_recording_while_the_job_asks_the_same(
    one_mug_job: Path, tmp_path: Path
) -> None:
    job = one_mug_job
    motions = [m.payload for m in read_messages(job) if m.topic.endswith("/input/motion")]
    assert motions
    assert all("result" in p for p in motions)
    report = _check(job)
    assert report.served["motion"] == len(motions)
    # A recorded plan for other arguments: the replay says so where the job asks, and plans itself on.
    first = {"done": False}

    def other_arguments(topic: str, payload: dict[str, object]) -> dict[str, object]:
        if topic == "input/motion" and not first["done"]:
            first["done"] = True
            return {**payload, "args_digest": "0" * 32}
        return payload

    changed = copy_recording(job, tmp_path / "other-job.mcap", other_arguments)
    report = replay(RecordedSession.load(changed))
    d = report.first_divergence
    assert d is not None
    assert d.what == "motion"
    assert report.replayed.final_state == "done"


def _stopped_after_the_first_placement() -> ServeHooks:
    """An operator who stops the job as soon as its first mug is placed."""
    contexts: list[ServeContext] = []
    stops: list[asyncio.Future[dict[str, object]]] = []

    def placed(topic: str, payload: Mapping[str, object]) -> None:
        if topic == "events" and payload.get("kind") == "mug_placed" and not stops:
            stops.append(asyncio.ensure_future(contexts[0].handle("stop", b"", False)))

    return ServeHooks(on_publish=(placed,), on_ready=contexts.append)


@pytest.mark.slow
def test_a_kinematic_job_on_the_full_size_tray_replays_to_a_match(tmp_path: Path) -> None:
    """A dataset other than 1, on the other tray: the stand-in is built from the header's scene (its dataset
    and tray). When the scene's view did not fit the kinematic world's tray, every such recording replayed
    in a dataset-1 stand-in on the robot tray and diverged at its first plan. The job is stopped once its
    first mug is placed: the plan and a whole cycle are what show it (the seven mugs more of the whole job
    were three quarters of the test's time)."""
    job = record_job(tmp_path, world="kinematic", dataset=4, hooks=_stopped_after_the_first_placement()).path
    report = _check(job)
    assert report.served["motion"] > 0
    assert report.served["plan"] == 1
    placed = [e.detail["mug_id"] for e in report.replayed.events if e.kind == "mug_placed"]
    assert len(placed) == 1
    assert placed == [e.detail["mug_id"] for e in report.recorded.events if e.kind == "mug_placed"]
    assert report.recorded.final_state == "idle"  # stopped, where the replay's stop came too


@pytest.mark.slow
def test_twenty_replays_of_one_recording_give_identical_traces(one_mug_job: Path) -> None:
    session = RecordedSession.load(one_mug_job)

    def trace(report: ReplayReport) -> object:
        t = report.replayed
        return (t.states, t.state_times_s, [e.to_json() for e in t.events], t.outputs, t.final_state)

    first = replay(session)
    assert first.match
    for _ in range(19):
        again = replay(session)
        assert again.match
        assert trace(again) == trace(first)


@pytest.mark.parametrize(
    ("error", "payload"),
    [
        (BusTimeout("servo 3 did not answer"), {}),
        (ServoHealthFault("servo 4 temperature 95 C is past its limit 70 C"), {}),
        (CameraFault("camera: no frame within 2.0 s"), {}),
        (BusLost("servo bus /dev/x is gone", port="/dev/x"), {}),
        (ServoFault("servo 3 reports overload", servo_id=3, bits=("overload",)), {}),
    ],
)
def test_a_recorded_driver_error_is_raised_again_as_itself(
    error: BaseException, payload: dict[str, object]
) -> None:
    from daemon.backend import failure_fields

    fields = failure_fields(error)
    again = recorded_failure(str(fields["error"]), convert(fields, Failure))
    assert type(again) is type(error)
    assert str(again) == str(error)
    for key in ("servo_id", "bits", "port"):
        if hasattr(error, key):
            assert getattr(again, key) == getattr(error, key)
    # An older recording names only the class: the same class all the same.
    assert type(recorded_failure(str(fields["error"]))) is type(error)
