"""Commands over a real loopback Zenoh session: each class of bad command is refused and changes nothing."""

from __future__ import annotations

import asyncio
import json
import os
import signal
import sys
import time
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any

import pytest
import zenoh
from hypothesis import given, settings
from hypothesis import strategies as st

from cli import credentials
from cli.commands.client import DEFAULT_ENDPOINT, Unreachable, request
from cli.main import main
from daemon.commands_handler import BadCommand, nested_deeper_than, parse
from daemon.config import load_config
from daemon.security import DEFAULT_PORT
from daemon.zenoh_session import session_config
from tests.daemon.conftest import free_port
from tests.fakes.daemon import running_daemon
from tests.fakes.job import make_backend, make_world

ROBOT = "cmdtest"

Client = Callable[[str, bytes], Awaitable[dict[str, Any]]]


def _with_daemon(tmp_path: Path, scenario: Callable[[str, Client], Awaitable[None]]) -> None:
    """Run an in-process daemon on a free port, then ``scenario(endpoint, send)`` against it."""
    config = load_config(overrides={"robot_id": ROBOT, "planner": {"method": "bh"}})

    async def go() -> None:
        async with running_daemon(config, make_backend(make_world(2)), tmp_path) as d:
            await scenario(d.endpoint, d.query)

    asyncio.run(go())


BAD = [
    ("fly", b"", "unknown command 'fly' (known: status, start, pause, resume, stop, estop, reset)"),
    (
        "start",
        b"{dataset: 1}",
        "payload is not valid JSON: Expecting property name enclosed in double quotes at line 1 column 2",
    ),
    ("start", b"\xff\xfe", "payload is not UTF-8 text: invalid start byte at byte 0"),
    ("start", b"[1, 2]", "payload must be a JSON object, got a list"),
    ("start", b'{"dataset": "one"}', "dataset: expected an integer in [1, 6], got 'one'"),
    ("start", b'{"dataset": true}', "dataset: expected an integer in [1, 6], got true"),
    ("start", b'{"dataset": 9}', "dataset: 9 is out of range; allowed [1, 6]"),
    ("start", b'{"dataset": 1, "mugs": []}', "give either dataset or mugs, not both"),
    ("start", b'{"speed": 2}', "speed: unknown key in start (known keys: dataset, mugs, planner)"),
    (
        "start",
        b'{"planner": {"method": "magic"}}',
        "planner.method: 'magic' is not one of auto, exact, bh, sa, ga, psop-n, psop-i, psok-n, psok-i",
    ),
    (
        "start",
        b'{"planner": {"time_limit_s": 0}}',
        "planner.time_limit_s: 0 is out of range; allowed [0.01, 600]",
    ),
    (
        "start",
        b'{"planner": {"time_limit_s": NaN}}',
        "planner.time_limit_s: nan is out of range; allowed [0.01, 600]",
    ),
    (
        "start",
        b'{"mugs": [{"id": "a", "type": "huge", "x_m": 0, "y_m": 0.3}]}',
        "mugs[0].type: 'huge' is not a configured mug type (big, small)",
    ),
    ("start", b'{"mugs": [{"id": "a", "type": "big", "x_m": 0}]}', "mugs[0].y_m: missing"),
    (
        "start",
        b'{"mugs": [{"id": "a", "type": "big", "x_m": 5, "y_m": 0.3}]}',
        "mugs[0].x_m: 5 is out of range; allowed [-2, 2]",
    ),
    (
        "start",
        b'{"mugs": [{"id": "a", "type": "big", "x_m": 0, "y_m": 0.3},'
        b' {"id": "a", "type": "big", "x_m": 0.2, "y_m": 0.3}]}',
        "mugs: id 'a' is used twice",
    ),
    ("pause", b'{"now": true}', "pause takes no arguments, got 'now'"),
    ("pause", b"", "cannot pause in state idle"),
    ("resume", b"", "cannot resume in state idle"),
    ("reset", b"", "cannot reset in state idle"),
    (
        "start",
        b'{"dataset": 2}',
        "dataset and mugs set up a simulated counter; this backend is real hardware",
    ),
    ("start", b"x" * 5000, "payload of 5000 bytes is larger than the limit of 4096 bytes"),
    (
        "start",
        b'{"dataset": 1' + b"0" * 399 + b"}",
        "dataset: an integer of 400 digits is out of range; allowed [1, 6]",
    ),
    (
        "start",
        b'{"mugs": [{"id": "a", "type": "big", "x_m": -1' + b"0" * 399 + b', "y_m": 0.3}]}',
        "mugs[0].x_m: an integer of 400 digits is out of range; allowed [-2, 2]",
    ),
    (
        "start",
        b'{"planner": {"time_limit_s": 1' + b"0" * 399 + b"}}",
        "planner.time_limit_s: an integer of 400 digits is out of range; allowed [0.01, 600]",
    ),
]


@pytest.mark.slow
def test_each_class_of_bad_command_is_refused_with_its_reason_and_changes_nothing(tmp_path: Path) -> None:
    async def scenario(endpoint: str, send: Client) -> None:
        before = await send("status", b"")
        assert before["ok"] is True
        for verb, payload, error in BAD:
            assert await send(verb, payload) == {"robot_id": ROBOT, "ok": False, "error": error}, (
                verb,
                payload,
            )
        after = await send("status", b"")
        assert (after["state"], after["transitions"]) == ("idle", 0)
        assert after["allowed"] == ["status", "start", "estop"]

    _with_daemon(tmp_path, scenario)


VERBS = ("status", "start", "pause", "resume", "stop", "estop", "reset")


@pytest.mark.slow
def test_deep_or_huge_payloads_are_refused_with_their_reason_for_every_verb(tmp_path: Path) -> None:
    deep = b"[" * 2000 + b"]" * 2000  # 4000 bytes: under the size limit, far past the nesting limit
    deep_object = b'{"mugs": ' + b'{"a": ' * 9 + b"1" + b"}" * 10

    async def scenario(endpoint: str, send: Client) -> None:
        for verb in VERBS:
            for payload in (deep, deep_object):
                assert await send(verb, payload) == {
                    "robot_id": ROBOT,
                    "ok": False,
                    "error": "command payload nested deeper than 8 levels",
                }, verb
            assert await send(verb, b" " * 4097) == {
                "robot_id": ROBOT,
                "ok": False,
                "error": "payload of 4097 bytes is larger than the limit of 4096 bytes",
            }, verb
            huge = b'{"x": "' + b"y" * 60_000 + b'"}'
            assert await send(verb, huge) == {
                "robot_id": ROBOT,
                "ok": False,
                "error": "payload of 60009 bytes is larger than the limit of 4096 bytes",
            }, verb

        def beyond_the_transport_limit() -> list[str | None]:
            with zenoh.open(session_config(listen=[], connect=[endpoint])) as s:
                replies = s.get(f"dishbot/{ROBOT}/cmd/start", payload=b" " * 200_000, timeout=1.0)
                return [r.err.payload.to_string() if r.err else None for r in replies]

        # Zenoh drops it before it is reassembled (``transport_limit_bytes``): nothing reaches the daemon.
        assert await asyncio.to_thread(beyond_the_transport_limit) == ["Timeout"]
        after = await send("status", b"")
        assert (after["state"], after["transitions"]) == ("idle", 0)

    _with_daemon(tmp_path, scenario)


def test_brackets_inside_strings_do_not_count_as_nesting() -> None:
    body = json.dumps({"mugs": [{"id": "[[[[[[[[[[", "type": '{{{{{{{{{{\\"[[[[', "x_m": 0, "y_m": 0}]})
    with pytest.raises(BadCommand, match=r"mugs\[0\]\.id: expected 1-32 letters"):
        parse("start", body.encode(), _CONFIG)
    assert nested_deeper_than(body, 3) is False
    assert nested_deeper_than(body, 2) is True


@pytest.mark.slow
def test_a_good_command_sequence_runs_a_job_over_zenoh(tmp_path: Path) -> None:
    async def scenario(endpoint: str, send: Client) -> None:
        assert await send("start", b'{"planner": {"method": "bh", "time_limit_s": 0.5}}') == {
            "robot_id": ROBOT,
            "ok": True,
            "state": "detect",
        }
        for _ in range(400):
            status = await send("status", b"")
            if status["state"] == "done":
                break
            await asyncio.sleep(0.01)
        assert status["state"] == "done"
        assert status["summary"]["placed"] == 2
        assert (await send("estop", b""))["state"] == "estop"
        assert (await send("reset", b""))["state"] == "idle"

    _with_daemon(tmp_path, scenario)


@pytest.mark.slow
def test_the_daemon_announces_itself_with_a_liveliness_token(tmp_path: Path) -> None:
    async def scenario(endpoint: str, send: Client) -> None:
        def alive() -> list[str]:
            with zenoh.open(session_config(listen=[], connect=[endpoint])) as s:
                # The query ends once answered; its timeout only bounds a silence (generous for a loaded
                # machine).
                tokens = s.liveliness().get("dishbot/*/alive", timeout=10.0)
                return [str(r.ok.key_expr) for r in tokens if r.ok]

        assert await asyncio.to_thread(alive) == [f"dishbot/{ROBOT}/alive"]

    _with_daemon(tmp_path, scenario)


@pytest.mark.slow
def test_the_client_verbs_print_the_reply_and_exit_by_its_outcome(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    async def scenario(endpoint: str, send: Client) -> None:
        base = ["--connect", endpoint, "--robot", ROBOT]
        assert await asyncio.to_thread(main, ["status", *base]) == 0
        assert await asyncio.to_thread(main, ["pause", *base]) == 1
        assert await asyncio.to_thread(main, ["status", *base, "--json"]) == 0

    _with_daemon(tmp_path, scenario)
    out, err = capsys.readouterr()
    printed = "".join(line for line in out.splitlines(keepends=True) if not line.startswith("20"))  # not logs
    assert printed.startswith(
        f"robot: {ROBOT}\nstate: idle\nmugs: 0 placed of 0 planned, 0 seen, 0 failed; current -\n"
    )
    assert f"dishbot pause: refused by robot {ROBOT!r}: cannot pause in state idle\n" in err
    assert json.loads(printed[printed.index("{") :])["state"] == "idle"


def test_a_client_with_no_daemon_says_so_and_exits_1(capsys: pytest.CaptureFixture[str]) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    assert main(["status", "--connect", endpoint, "--robot", "nobody", "--timeout", "0.5"]) == 1
    assert capsys.readouterr().err == (
        f"dishbot status: cannot connect to {endpoint}: Connection refused "
        "(is the daemon running, is the address right?)\n"
    )


def test_a_bad_client_endpoint_is_a_usage_error(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["status", "--connect", "127.0.0.1:3474"]) == 2
    assert capsys.readouterr().err == (
        "dishbot status: error: --connect: '127.0.0.1:3474' is not a Zenoh endpoint like tcp/127.0.0.1:3474 "
        "(protocol tcp, udp, tls, quic or ws; port 1-65535)\n"
    )


def test_the_default_port_is_dishbots_own_not_one_a_common_zenoh_or_dds_deployment_holds() -> None:
    """Issue 23 item 8: on Zenoh's 7447 the quick start failed beside a zenohd or ROS 2 rmw_zenoh router,
    and the client verbs talked to that router."""
    listen = load_config().zenoh.listen
    assert listen == (f"tcp/127.0.0.1:{DEFAULT_PORT}",)
    assert listen[0] == DEFAULT_ENDPOINT  # the client verbs reach the quick start's daemon
    assert credentials.plan("r1", operators=["alice"]).endpoint().endswith(f":{DEFAULT_PORT}")
    assert DEFAULT_PORT not in (7446, 7447)  # Zenoh's scouting and default ports (zenohd, rmw_zenoh, bridges)
    assert DEFAULT_PORT < 7400  # RTPS (DDS, ROS 2) takes 7400 + 250 * domain + offsets, from 7400 up


def test_request_raises_unreachable_when_nothing_listens() -> None:
    with pytest.raises(Unreachable, match=r"cannot connect to tcp/127\.0\.0\.1:"):
        request(f"tcp/127.0.0.1:{free_port()}", "ghost", "status", {}, timeout_s=0.3)


_CONFIG = load_config()
_json = st.recursive(
    st.none() | st.booleans() | st.integers(-10, 10) | st.floats(allow_nan=False) | st.text(max_size=5),
    lambda inner: st.lists(inner, max_size=3) | st.dictionaries(st.text(max_size=8), inner, max_size=3),
    max_leaves=10,
)


@settings(max_examples=200, deadline=None)
@given(verb=st.sampled_from(["start", "pause", "status", "nope"]), body=_json)
@pytest.mark.slow
def test_the_parser_accepts_or_refuses_any_json_with_a_bad_command_error(verb: str, body: object) -> None:
    config = _CONFIG
    message = "accepted"
    try:
        parse(verb, json.dumps(body).encode(), config)
    except BadCommand as e:
        message = str(e)
    assert message
    assert "\n" not in message


_NUMERIC_FIELDS: dict[str, Callable[[int], dict[str, object]]] = {
    "dataset": lambda n: {"dataset": n},
    "planner.seed": lambda n: {"planner": {"seed": n}},
    "planner.time_limit_s": lambda n: {"planner": {"time_limit_s": n}},
    "mugs[0].x_m": lambda n: {"mugs": [{"id": "a", "type": "big", "x_m": n, "y_m": 0.3}]},
    "mugs[0].y_m": lambda n: {"mugs": [{"id": "a", "type": "big", "x_m": 0.3, "y_m": n}]},
}


@settings(max_examples=200, deadline=None)
@given(
    field=st.sampled_from(sorted(_NUMERIC_FIELDS)),
    number=st.integers() | st.integers(10**300, 10**1200) | st.integers(-(10**1200), -(10**300)),
)
def test_any_integer_in_a_numeric_field_is_accepted_or_refused_in_one_line_naming_it(
    field: str, number: int
) -> None:
    body = json.dumps(_NUMERIC_FIELDS[field](number)).encode()
    try:
        parse("start", body, _CONFIG)
    except BadCommand as e:
        message = str(e)
        assert message.startswith(f"{field}: ")
        assert "out of range" in message
        assert len(message) < 100


@pytest.mark.slow
def test_monitor_prints_state_changes_and_events_of_a_running_job(tmp_path: Path) -> None:
    """The monitor, as a user runs it (its own process, piped), prints the job's state changes and events. It
    is stopped with Ctrl-C once it has shown a placed mug: no wall-clock window the job must fit in."""
    seen: list[str] = []

    async def scenario(endpoint: str, send: Client) -> None:
        watch = await asyncio.create_subprocess_exec(
            *[sys.executable, "-m", "cli.main", "monitor", "--connect", endpoint, "--robot", ROBOT],
            stdout=asyncio.subprocess.PIPE,
            stderr=asyncio.subprocess.STDOUT,
            env={**os.environ, "PYTHONUNBUFFERED": "1"},
        )
        assert watch.stdout is not None
        out = watch.stdout

        async def until(what: str, prefix: str) -> None:
            while not any(line.startswith(prefix) for line in seen):
                line = await asyncio.wait_for(out.readline(), 120)  # a generous bound on a hang, not a timing
                assert line, f"the monitor ended before any {what}: {seen}"
                seen.append(line.decode().rstrip("\n"))

        try:
            await until("state", "state ")
            await send("start", b"")
            await until("placed mug", "event mug_placed ")
            watch.send_signal(signal.SIGINT)
            rest, _ = await asyncio.wait_for(watch.communicate(), 60)
            seen.extend(rest.decode().splitlines())
            assert watch.returncode == 0
        finally:
            if watch.returncode is None:
                watch.kill()
                await watch.wait()

    _with_daemon(tmp_path, scenario)
    shown = [line for line in seen if line.startswith(("state ", "event "))]
    assert shown[0] == "state idle  placed 0"
    assert "state detect  placed 0" in shown
    assert any(line.startswith("event mug_placed ") for line in shown)


def test_the_monitor_panel_shows_state_joints_and_force() -> None:
    from cli.commands.monitor import panel
    from wire.messages import Gripper, Joints, State

    text = panel(
        {
            "state": State(
                state="flip.turn",
                current_mug="m3",
                mugs_placed=1,
                mugs_planned=4,
                mugs_total=5,
                mugs_failed=0,
                t=0.0,
            ),
            "joints": Joints(t=0.0, names=["a", "b"], position_rad=[0.1, -1.25]),
            "gripper": Gripper(t=0.0, aperture_m=0.0725, force_n=3.0, holding=True),
        },
        "r1",
        "tcp/127.0.0.1:3474",
    )
    assert text.splitlines() == [
        "dishbot r1 @ tcp/127.0.0.1:3474",
        "state   flip.turn   mug m3   placed 1/4  seen 5  failed 0",
        "joints  a +0.100  b -1.250",
        "gripper aperture 72.5 mm  force 3.00 N  holding",
    ]


def _depth(value: object) -> int:
    if isinstance(value, dict):
        return 1 + max((_depth(v) for v in value.values()), default=0)
    if isinstance(value, list):
        return 1 + max((_depth(v) for v in value), default=0)
    return 0


_bracket_text = st.text(alphabet='[]{}"\\ ab', max_size=6)
_nested = st.recursive(
    st.none() | st.integers(-3, 3) | _bracket_text,
    lambda inner: st.lists(inner, max_size=3) | st.dictionaries(_bracket_text, inner, max_size=3),
    max_leaves=12,
)


@settings(max_examples=300, deadline=None)
@given(body=_nested, levels=st.integers(0, 6))
def test_the_nesting_check_agrees_with_the_parsed_depth(body: object, levels: int) -> None:
    assert nested_deeper_than(json.dumps(body), levels) == (_depth(body) > levels)


@pytest.mark.slow
def test_a_command_flood_with_a_slow_subscriber_is_answered_in_full_and_changes_nothing(
    tmp_path: Path,
) -> None:
    """Row 14 of the fault matrix: four clients, each with its own session, send 300 commands as fast as
    they get answers (status, and pause/resume/stop refused in idle) while a subscriber to every topic takes
    50 ms per message. Every command gets its answer, the refused ones change nothing, and the daemon's
    telemetry goes on being published."""

    async def scenario(endpoint: str, send: Client) -> None:
        seen: list[str] = []

        def slow(sample: zenoh.Sample) -> None:
            seen.append(str(sample.key_expr))
            time.sleep(0.05)  # a slow subscriber: Zenoh's thread, never the daemon's loop

        def client(verbs: list[str]) -> list[tuple[str, dict[str, Any]]]:
            out = []
            with zenoh.open(session_config(listen=[], connect=[endpoint])) as session:
                for verb in verbs:
                    replies = list(session.get(f"dishbot/{ROBOT}/cmd/{verb}", payload=b"", timeout=5.0))
                    ok = replies[0].ok
                    assert ok is not None, f"{verb}: no answer"
                    out.append((verb, json.loads(ok.payload.to_bytes())))
            return out

        with zenoh.open(session_config(listen=[], connect=[endpoint])) as watcher:
            subscriber = watcher.declare_subscriber(f"dishbot/{ROBOT}/**", slow)
            verbs = ["status", "pause", "resume", "stop"] * 19
            answered = await asyncio.gather(*(asyncio.to_thread(client, verbs[i:]) for i in range(4)))
            for _ in range(100):  # telemetry still reaches the slow subscriber (it lags, by design)
                if any(k.endswith("/state") for k in seen):
                    break
                await asyncio.sleep(0.1)
            subscriber.undeclare()  # type: ignore[no-untyped-call]
        replies = [r for batch in answered for r in batch]
        assert len(replies) == sum(len(verbs[i:]) for i in range(4)) == 298
        for verb, reply in replies:
            if verb == "status":
                assert reply["ok"] is True
                assert reply["state"] == "idle"
            else:
                assert reply == {"robot_id": ROBOT, "ok": False, "error": f"cannot {verb} in state idle"}
        assert any(k.endswith("/state") for k in seen)  # telemetry kept coming meanwhile
        after = await send("status", b"")
        assert after["state"] == "idle"

    _with_daemon(tmp_path, scenario)
