"""The operator's verbs as Foxglove services: offered on loopback only, answered by the daemon's own command
path (the same validation and the same replies as over Zenoh), able to start and stop a simulated job."""

from __future__ import annotations

import asyncio
import json
import time
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any

import pytest
import websockets
from structlog.testing import capture_logs
from websockets.typing import Subprotocol

from daemon.commands_handler import VERBS
from daemon.config import load_config
from recorder import read_messages
from recorder.foxglove_server import LiveServer
from tests.daemon.test_commands import BAD
from tests.fakes.daemon import running_daemon
from tests.fakes.job import make_backend, make_world
from tests.recorder.foxglove_client import FoxgloveClient

ROBOT = "cmdtest"


def _with_daemon(tmp_path: Path, scenario: Callable[[FoxgloveClient], Awaitable[None]]) -> list[Any]:
    """An in-process daemon (the fake cell) serving Foxglove on loopback; ``scenario(client)`` against it.
    Returns the daemon's log events."""
    config = load_config(overrides={"robot_id": ROBOT, "planner": {"method": "bh"}})

    async def go() -> None:
        backend = make_backend(make_world(2))
        async with running_daemon(config, backend, tmp_path, foxglove=("127.0.0.1", 0)):
            url = next(e["foxglove"] for e in logs if e["event"] == "daemon_ready")
            client = await FoxgloveClient.connect(url)
            try:
                deadline = time.monotonic() + 60  # a guard: the services come at once, later at load
                while len(client.services) < len(VERBS):
                    await client.receive(deadline)
                await scenario(client)
            finally:
                await client.close()

    with capture_logs() as logs:
        asyncio.run(go())
    return logs


@pytest.mark.slow
def test_every_verb_is_a_service_and_a_bad_command_gets_the_zenoh_reply(tmp_path: Path) -> None:
    async def scenario(client: FoxgloveClient) -> None:
        assert sorted(client.services) == sorted(f"dishbot/{ROBOT}/cmd/{v}" for v in VERBS)
        start = client.services[f"dishbot/{ROBOT}/cmd/start"]
        assert (start["request"]["encoding"], start["request"]["schemaEncoding"]) == ("json", "jsonschema")
        for verb, payload, error in BAD:
            if verb not in VERBS:
                continue
            reply = await client.call_raw(f"dishbot/{ROBOT}/cmd/{verb}", payload)
            assert reply == {"robot_id": ROBOT, "ok": False, "error": error}, (verb, payload)
        status = await client.call(f"dishbot/{ROBOT}/cmd/status", {})
        assert (status["state"], status["transitions"]) == ("idle", 0)

    _with_daemon(tmp_path, scenario)


@pytest.mark.slow
def test_a_service_call_starts_and_another_stops_a_simulated_job(tmp_path: Path) -> None:
    state = f"dishbot/{ROBOT}/state"

    async def scenario(client: FoxgloveClient) -> None:
        await client.advertised({state})
        await client.subscribe([state])
        started = await client.call(f"dishbot/{ROBOT}/cmd/start", {"planner": {"method": "bh"}})
        assert started == {"robot_id": ROBOT, "ok": True, "state": "detect"}
        mark = len(client.received)  # what the job published from here on
        stopped = await client.call(f"dishbot/{ROBOT}/cmd/stop", {})
        assert stopped["ok"] is True, stopped
        # The job winds down on its own time after the reply: wait for the state message saying idle (as
        # long as a loaded machine needs), not for a wall-clock number of status polls.
        states = [json.loads(m.data)["state"] for m in client.received[mark:] if m.topic == state]
        if "idle" not in states:
            await client.until(state, lambda m: json.loads(m.data)["state"] == "idle", timeout_s=120)
        status = await client.call(f"dishbot/{ROBOT}/cmd/status", {})
        assert status["state"] == "idle"
        assert status["transitions"] >= 2

    _with_daemon(tmp_path, scenario)
    # The commands went through the daemon's command path: recorded as inputs, as those from Zenoh are.
    commands = [
        m.payload["verb"]
        for path in sorted(tmp_path.glob("*.mcap"))
        for m in read_messages(path)
        if m.topic == f"dishbot/{ROBOT}/input/command"
    ]
    assert commands == ["start", "stop"]


def test_off_loopback_no_command_is_offered_and_a_log_line_says_why() -> None:
    server = LiveServer("0.0.0.0", 0, name="open")
    try:

        async def handle(verb: str, payload: bytes, many: bool) -> dict[str, object]:
            raise AssertionError("never called")

        with capture_logs() as logs:
            offered = server.offer_commands(
                asyncio.new_event_loop(), handle, "r1", VERBS, max_payload_bytes=4096
            )
        assert offered == []
        assert logs == [
            {
                "event": "foxglove_commands_not_offered",
                "log_level": "warning",
                "host": "0.0.0.0",
                "reason": "the server is not on loopback and has no authentication: command over Zenoh",
            }
        ]

        async def advertised() -> dict[str, Any]:
            client = await FoxgloveClient.connect(f"ws://127.0.0.1:{server.port}")
            try:
                while not client.server_info:
                    await client.receive(time.monotonic() + 60)
                return client.server_info
            finally:
                await client.close()

        info = asyncio.run(advertised())
        assert "services" not in info["capabilities"]
    finally:
        server.close()


def test_a_client_asking_only_for_the_older_protocol_is_refused_with_http_400() -> None:
    server = LiveServer("127.0.0.1", 0, name="v1")

    async def connect() -> None:
        async with websockets.connect(
            server.url, subprotocols=[Subprotocol("foxglove.websocket.v1")]
        ) as ws:  # pragma: no cover - refused
            await ws.recv()

    try:
        with pytest.raises(websockets.InvalidStatus) as err:
            asyncio.run(connect())
        assert err.value.response.status_code == 400
    finally:
        server.close()
