"""Fleets over a real Zenoh router on loopback: wildcard robot ids, replies that say who answered, liveliness,
connection health, and the client's checks of robot ids and start arguments."""

from __future__ import annotations

import asyncio
import contextlib
import json
import signal
import sys
import time
from pathlib import Path
from typing import Any

import pytest
import zenoh
from hypothesis import given
from hypothesis import strategies as st

from cli.commands.client import Target
from cli.commands.monitor import RobotView, Watch, panel, screen
from cli.main import main
from daemon.commands_handler import VERBS
from daemon.zenoh_session import addressed, session_config
from recorder import read_messages
from tests.daemon.conftest import free_port
from tests.daemon.daemons import ask, cli, daemon, robot_config, router, until_state
from wire.messages import Gripper, Joints, State, convert

ONLY_FLEET_VERBS = "(only status and estop may go to every robot at once)"
REFUSED_MANY = f"addressed to many robots is refused: name one robot {ONLY_FLEET_VERBS}"


@pytest.mark.parametrize(
    ("query", "verb", "many", "error"),
    [
        ("dishbot/r1/cmd/status", "status", False, None),
        ("dishbot/*/cmd/status", "status", True, None),
        ("dishbot/r$*/cmd/estop", "estop", True, None),
        ("dishbot/**/start", "start", True, None),
        ("dishbot/r1/cmd/fly", "fly", False, None),
        ("dishbot/*/cmd/fly", "fly", True, None),
        (
            "dishbot/r1/cmd/*",
            "",
            False,
            "names 7 commands (status, start, pause, resume, stop, estop, reset)",
        ),
        ("dishbot/r1/cmd/st$*", "", False, "names 3 commands (status, start, stop)"),
        ("dishbot/*/cmd/x$*", "", True, "names no command"),
    ],
)
def test_the_verb_comes_from_intersecting_the_query_with_the_robots_own_keys(
    query: str, verb: str, many: bool, error: str | None
) -> None:
    target = addressed(query, "r1", VERBS)
    assert (target.verb, target.many) == (verb, many)
    if error is None:
        assert target.error is None
        assert target.reply_key == f"dishbot/r1/cmd/{verb}"  # always this robot's own concrete key
    else:
        assert target.error == f"the query {query} {error}; ask for one cmd/<verb>"


@given(robot=st.from_regex(r"[A-Za-z0-9_-]{1,20}", fullmatch=True), verb=st.sampled_from(VERBS))
def test_a_concrete_command_key_is_always_that_command(robot: str, verb: str) -> None:
    target = addressed(f"dishbot/{robot}/cmd/{verb}", robot, VERBS)
    assert (target.verb, target.many, target.error) == (verb, False, None)


@pytest.mark.slow
def test_a_fleet_behind_a_router_answers_wildcards_with_each_robots_own_id(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    hub = f"tcp/127.0.0.1:{free_port()}"

    async def scenario() -> None:
        with router(hub):
            async with (
                daemon(tmp_path, robot_config("r1"), listen=[], connect=[hub]),
                daemon(tmp_path, robot_config("r2"), listen=[], connect=[hub]),
            ):
                await _until(lambda: len(ask(hub, "dishbot/*/cmd/status")) == 2)
                code, out, _ = await cli(capsys, "status", "--connect", hub, "--robot", "*")
                assert code == 0
                assert [line.split()[:3] for line in out.splitlines()] == [
                    ["robot", "ok", "state"],
                    ["r1", "yes", "idle"],
                    ["r2", "yes", "idle"],
                ]
                code, out, _ = await cli(capsys, "list", "--connect", hub)
                assert (code, out) == (0, "r1\nr2\n")
                # A wildcard start is refused by each daemon itself, on its own key, with its own id.
                started = await asyncio.to_thread(ask, hub, "dishbot/*/cmd/start")
                assert sorted(started, key=lambda r: r[0]) == [
                    (f"dishbot/{r}/cmd/start", {"robot_id": r, "ok": False, "error": f"start {REFUSED_MANY}"})
                    for r in ("r1", "r2")
                ]
                code, _, err = await cli(capsys, "start", "--connect", hub, "--robot", "*")
                assert code == 2
                assert err == (
                    "dishbot start: error: --robot '*': start goes to one robot at a time; name it "
                    "(only status and estop go to every robot at once)\n"
                )
                code, _, err = await cli(
                    capsys, "status", "--connect", hub, "--robot", "r3", "--timeout", "1"
                )
                assert (code, err) == (
                    1,
                    f"dishbot status: no robot 'r3' at {hub}; robots alive there: r1, r2\n",
                )
                code, out, _ = await cli(capsys, "estop", "--connect", hub, "--robot", "*", "--json")
                assert code == 0
                assert [(r["robot_id"], r["state"]) for r in json.loads(out)] == [
                    ("r1", "estop"),
                    ("r2", "estop"),
                ]
                several = await asyncio.to_thread(ask, hub, "dishbot/r1/cmd/*")
                assert several == [
                    (
                        "error",
                        {
                            "robot_id": "r1",
                            "ok": False,
                            "error": "the query dishbot/r1/cmd/* names 7 commands (status, start, pause, "
                            "resume, stop, estop, reset); ask for one cmd/<verb>",
                        },
                    )
                ]

    asyncio.run(scenario())


def test_a_reply_from_another_robot_than_named_is_not_trusted(capsys: pytest.CaptureFixture[str]) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"

    def impostor(query: zenoh.Query) -> None:
        query.reply("dishbot/r9/cmd/status", json.dumps({"ok": True, "robot_id": "evil", "state": "idle"}))
        query.drop()  # type: ignore[no-untyped-call]  # zenoh's stub leaves it untyped

    with zenoh.open(session_config(listen=[endpoint], connect=[])) as session:
        queryable = session.declare_queryable("dishbot/r9/cmd/**", impostor)
        assert main(["status", "--connect", endpoint, "--robot", "r9"]) == 1
        queryable.undeclare()  # type: ignore[no-untyped-call]  # zenoh's stub leaves it untyped
    assert capsys.readouterr().err == (
        "dishbot status: robot 'evil' answered, not 'r9' as named: check the robot ids on this network\n"
    )


@pytest.mark.slow
def test_the_daemon_says_once_when_it_loses_its_router_and_once_when_it_is_back(tmp_path: Path) -> None:
    hub = f"tcp/127.0.0.1:{free_port()}"
    direct = f"tcp/127.0.0.1:{free_port()}"

    async def scenario() -> Path:
        events: list[dict[str, Any]] = []
        with router(hub) as first, contextlib.ExitStack() as later:  # both outlive the daemon
            async with daemon(tmp_path, robot_config("r1"), listen=[direct], connect=[hub]) as d:
                with zenoh.open(session_config(listen=[], connect=[direct], mode="client")) as watcher:
                    watcher.declare_subscriber(
                        "dishbot/r1/events", lambda s: events.append(json.loads(s.payload.to_bytes()))
                    )
                    await _until(lambda: bool(d.session.session.info.routers_zid()))
                    first.close()  # type: ignore[no-untyped-call]
                    await _until(lambda: any(e["kind"] == "connection_lost" for e in events))
                    later.enter_context(router(hub))
                    await _until(lambda: any(e["kind"] == "connection_restored" for e in events))
                    await until_state(direct, "idle")
                    lost = next(e for e in events if e["kind"] == "connection_lost")
                    assert (lost["peers"], lost["routers"], lost["state"]) == (0, 0, "idle")
                return d.recording

    recording = asyncio.run(scenario())
    recorded = [m.payload["kind"] for m in read_messages(recording) if m.topic == "dishbot/r1/events"]
    assert [kind for kind in recorded if str(kind).startswith("connection_")] == [
        "connection_lost",
        "connection_restored",
    ]


@pytest.mark.slow
def test_a_daemon_that_reaches_no_router_at_start_says_so_once(tmp_path: Path) -> None:
    nowhere = f"tcp/127.0.0.1:{free_port()}"

    async def scenario() -> Path:
        async with daemon(tmp_path, robot_config("r1"), listen=[], connect=[nowhere]) as d:
            await asyncio.sleep(2.5)  # longer than the health report settles (1 s) and a few retries
        return d.recording

    recorded = [m.payload for m in read_messages(asyncio.run(scenario())) if m.topic == "dishbot/r1/events"]
    assert [(e["kind"], e["routers"]) for e in recorded if str(e["kind"]).startswith("connection_")] == [
        ("connection_lost", 0)
    ]


@pytest.mark.slow
def test_monitor_shows_every_robot_and_says_when_one_is_gone(tmp_path: Path) -> None:
    """``dishbot monitor --robot '*'`` as a user runs it (its own process, output piped), stopped with
    Ctrl-C once it has said what it should: it waits for each line, not for fixed seconds."""
    hub = f"tcp/127.0.0.1:{free_port()}"
    idle = ["r1: state idle  placed 0", "r2: state idle  placed 0"]

    async def scenario() -> list[str]:
        with router(hub):
            async with daemon(tmp_path, robot_config("r1"), listen=[], connect=[hub]):
                monitor = await asyncio.create_subprocess_exec(
                    *(sys.executable, "-m", "cli.main", "monitor", "--connect", hub, "--robot", "*"),
                    stdout=asyncio.subprocess.PIPE,
                )
                try:
                    async with daemon(tmp_path, robot_config("r2"), listen=[], connect=[hub]):
                        await _until(lambda: len(ask(hub, "dishbot/*/cmd/status")) == 2)
                        lines = await _printed(monitor, *idle)
                    lines += await _printed(monitor, "r2: daemon gone (liveliness token dropped)")
                finally:
                    monitor.send_signal(signal.SIGINT)
                    async with asyncio.timeout(60):
                        assert await monitor.wait() == 0  # Ctrl-C ends the monitor quietly
                assert monitor.stdout is not None
                return lines + (await monitor.stdout.read()).decode().splitlines()

    lines = asyncio.run(scenario())
    assert "r1: daemon gone (liveliness token dropped)" not in lines


async def _printed(process: asyncio.subprocess.Process, *expected: str, timeout_s: float = 60.0) -> list[str]:
    """The lines ``process`` prints until it has printed every one of ``expected``; the test fails if it
    ends first or takes longer than ``timeout_s`` (a hang, not a measurement)."""
    assert process.stdout is not None
    lines: list[str] = []
    async with asyncio.timeout(timeout_s):
        while not set(expected) <= set(lines):
            line = await process.stdout.readline()
            assert line, f"the monitor ended before printing {expected}: {lines}"
            lines.append(line.decode().rstrip("\n"))
    return lines


def test_the_monitor_screen_keeps_the_last_events_and_fits_80_columns() -> None:
    watch = Watch(many=False)
    long_state = {
        "state": "side_grasp.approach",
        "current_mug": "mug-with-a-very-long-identifier",
        "mugs_placed": 10,
        "mugs_planned": 30,
        "mugs_total": 30,
        "mugs_failed": 0,
    }
    view = watch.robot("r1")
    view.values = {
        "state": convert({**long_state, "t": 0.0}, State),
        "joints": Joints(
            t=0.0,
            names=["shoulder_turn", "shoulder_lift", "elbow_lift", "wrist_lift", "wrist_turn"],
            position_rad=[0.0, -1.4, 2.0, 1.0, -1.5708],
        ),
        "gripper": Gripper(t=0.0, aperture_m=0.12, force_n=None, holding=False),
    }
    view.alive = True
    for i in range(12):
        watch.add_line(
            "r1", f"event mug_placed {json.dumps({'mug_id': f'm{i}', 'x_m': 0.123456789} | long_state)}", True
        )
    target = Target("tls/robot.example.org:3474", "r1")
    first = screen(watch, target, linked=True).splitlines()
    again = screen(watch, target, linked=True).splitlines()
    assert first == again  # events stay on screen, frame after frame
    assert all(len(line) <= 80 for line in first), [line for line in first if len(line) > 80]
    assert [line.split()[2] for line in first if "event mug_placed" in line] == ["mug_placed"] * 8
    assert first[first.index("recent events:") + 1].endswith("…")
    assert first[2:4] == [
        "joints  shoulder_turn +0.000  shoulder_lift -1.400  elbow_lift +2.000",
        "        wrist_lift +1.000  wrist_turn -1.571",
    ]


def test_a_gone_daemon_is_shown_as_gone_not_as_its_last_state() -> None:
    state = State(state="flip.turn", mugs_total=0, mugs_placed=0, t=0.0)
    view = RobotView(values={"state": state}, alive=False, changed_at=0.0)
    text = panel(view.values, "r1", "tcp/127.0.0.1:3474", alive=view.alive, since=view.changed_at)
    lines = text.splitlines()
    assert lines[1].startswith("daemon GONE at ")
    assert lines[1].endswith(": its liveliness token dropped")
    assert lines[2:] == ["last state flip.turn (no longer current)"]
    assert "state   flip.turn" not in text


@pytest.mark.parametrize("robot", ["dish$bot", "", "a#b", "a/b", "x" * 65])
@pytest.mark.parametrize("verb", ["status", "start", "estop", "monitor"])
def test_a_bad_robot_id_is_a_one_line_usage_error(
    robot: str, verb: str, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main([verb, "--robot", robot, "--connect", f"tcp/127.0.0.1:{free_port()}"]) == 2
    assert capsys.readouterr().err == (
        f"dishbot {verb}: error: --robot: {robot!r} is not a robot id; use 1-64 letters, digits, '_' or '-' "
        "(or '*' for every robot)\n"
    )


@pytest.mark.parametrize(
    ("argv", "error"),
    [
        (["start", "--dataset", "99"], "--dataset 99: choose a dataset 1-6"),
        (["start", "--dataset", "0"], "--dataset 0: choose a dataset 1-6"),
        (["start", "--time-limit", "0"], "--time-limit 0: choose 0.01-600 seconds"),
        (
            ["start", "--method", "magic"],
            "--method magic: choose one of auto, exact, bh, sa, ga, psop-n, psop-i, psok-n, psok-i",
        ),
        (["start", "--cost", "cheap"], "--cost cheap: choose one of bpc, upc, ec"),
        (
            ["pause", "--robot", "*"],
            "--robot '*': pause goes to one robot at a time; name it (only status and estop go to "
            "every robot at once)",
        ),
        (["status", "--timeout", "0"], "--timeout 0: choose 0-600 seconds"),
        (
            ["list", "--connect", "robot:3474"],
            "--connect: 'robot:3474' is not a Zenoh endpoint like tcp/127.0.0.1:3474 (protocol tcp, "
            "udp, tls, quic or ws; port 1-65535)",
        ),
    ],
)
def test_bad_client_input_is_refused_before_anything_is_sent(
    argv: list[str], error: str, capsys: pytest.CaptureFixture[str]
) -> None:
    nobody = f"tcp/127.0.0.1:{free_port()}"  # nothing listens: the error must come before connecting
    extra = [] if "--connect" in argv else ["--connect", nobody]
    assert main([*argv, *extra]) == 2
    assert capsys.readouterr().err == f"dishbot {argv[0]}: error: {error}\n"


async def _until(condition: Any, *, timeout_s: float = 20.0) -> None:
    """Poll ``condition`` (run off the loop) until it holds; the test fails if it never does."""
    deadline = time.monotonic() + timeout_s
    while not await asyncio.to_thread(condition):
        assert time.monotonic() < deadline, "condition never held"
        await asyncio.sleep(0.05)
