"""The live Foxglove server: a WebSocket client speaking Foxglove's protocol connects, sees the channels
advertised, subscribes, and receives the latched scene at once and then the messages as they are recorded."""

from __future__ import annotations

import asyncio
import collections
import math
from pathlib import Path

import pytest
import websockets
from websockets.typing import Subprotocol

from cli.main import main
from daemon.config import check_foxglove_listen, load_config
from daemon.errors import ConfigError
from daemon.hardware import scene_view
from recorder import Recorder, read_messages
from recorder.errors import LiveServerError
from recorder.foxglove_server import LiveServer, known_channels
from recorder.writer import json_channel
from tests.recorder.foxglove_client import SUBPROTOCOL, FoxgloveClient

T = 1_790_000_000_000_000_000
JOINTS = ["shoulder_turn", "shoulder_lift", "elbow_lift", "wrist_lift", "wrist_turn"]


def joints(q0: float) -> dict[str, object]:
    return {
        "t": 0.0,
        "names": JOINTS,
        "position_rad": [q0, -0.8, 1.6, 0.4, -1.57],
        "velocity_rad_s": [0.0] * 5,
    }


def test_a_foxglove_client_gets_the_advertised_channels_latched_scene_and_messages(tmp_path: Path) -> None:
    async def scenario() -> None:
        server = LiveServer("127.0.0.1", 0, name="dishbot test")
        recorder = Recorder(
            tmp_path / "live.mcap", chunk_size=1024, deriver=scene_view(load_config()), tee=server
        )
        try:
            recorder.write_header({"robot_id": "r1"}, {}, log_time_ns=T)
            recorder.write("dishbot/r1/joints", joints(0.1), log_time_ns=T + 1)
            recorder.write(
                "dishbot/r1/state",
                {"state": "idle", "mugs_total": 0, "mugs_placed": 0, "t": 0.0},
                log_time_ns=T + 2,
            )
            # The recorder's thread declares the channels: connect once they exist. A channel declared
            # while a client's handshake is under way can reach it advertised but unknown to the server's
            # record of that client (foxglove-sdk: "attempted to subscribe to unknown channel"); the
            # daemon declares every channel it can record before its server starts (the next test).
            topics = {"/tf", "/scene/arm", "/scene/cell", "dishbot/r1/joints", "dishbot/r1/state"}
            for _ in range(3000):
                if topics <= server.declared():
                    break
                await asyncio.sleep(0.01)
            async with websockets.connect(server.url, subprotocols=[Subprotocol(SUBPROTOCOL)]) as ws:
                assert ws.subprotocol == SUBPROTOCOL
                client = FoxgloveClient(ws)
                await client.advertised(topics)
                assert client.server_info["name"] == "dishbot test"
                await client.subscribe(["/scene/arm", "/scene/cell", "dishbot/r1/state", "/tf"])
                latched = {m.topic: (m.log_time_ns, m.data) for m in await client.messages(4)}
                assert set(latched) == {"/scene/arm", "/scene/cell", "dishbot/r1/state", "/tf"}
                arm = client.decode("/scene/arm", latched["/scene/arm"][1])
                assert {e.frame_id for e in arm.entities} >= {"base_link", "upper_arm_link", "gripper_link"}
                assert client.decode("dishbot/r1/state", latched["dishbot/r1/state"][1])["state"] == "idle"
                recorder.write("dishbot/r1/joints", joints(0.7), log_time_ns=T + 3)
                ((topic, log_time, data),) = [
                    (m.topic, m.log_time_ns, m.data) for m in await client.messages(1)
                ]
                assert (topic, log_time) == ("/tf", T + 3)
                tf = client.decode("/tf", data)
                turret = next(t for t in tf.transforms if t.child_frame_id == "turret_link")
                assert turret.parent_frame_id == "base_link"
                assert turret.rotation.z == pytest.approx(math.sin(0.7 / 2))  # 0.7 rad about the base's z
        finally:
            await asyncio.to_thread(recorder.close)
            server.close()
        recorded = read_messages(tmp_path / "live.mcap")
        assert (
            recorded.topic_counts["/tf"] == 3
        )  # the opening and the two samples: the same channel in the file

    asyncio.run(scenario())


def test_every_known_channel_is_declared_before_its_first_message_which_no_subscriber_misses(
    tmp_path: Path,
) -> None:
    """A client connected to a server that has sent nothing yet sees every channel the daemon can record
    (the header, the JSON topics, the Foxglove scene) in one advertisement, and gets the first message of
    each of a job's inputs and outputs."""

    async def scenario() -> None:
        server = LiveServer("127.0.0.1", 0, name="declared", channels=known_channels("r1", scene=True))
        recorder = Recorder(
            tmp_path / "first.mcap", chunk_size=1024, deriver=scene_view(load_config()), tee=server
        )
        try:
            client = await FoxgloveClient.connect(server.url)
            expected = {c.topic for c in known_channels("r1", scene=True)}
            await client.advertised(expected)
            assert {"session/header", "dishbot/r1/input/command", "/events", "/scene/plan"} <= expected
            server.send(json_channel("dishbot/r1/state"), b'{"state": "idle"}', T - 1)
            await client.subscribe(sorted(client.topics()))
            await client.messages(1)  # the latched state: the subscriptions are in place
            firsts: dict[str, dict[str, object]] = {
                "dishbot/r1/input/command": {"t": 0.0, "verb": "start", "payload": "{}", "reply": {}},
                "dishbot/r1/input/grasp": {"t_start": 0.0, "t_end": 1.0},
                "dishbot/r1/output/gripper": {"aperture_m": 0.05},
                "dishbot/r1/events": {"kind": "transition", "source": "idle", "dest": "detect"},
            }
            recorder.write_header({"robot_id": "r1"}, {}, log_time_ns=T)
            for i, (topic, payload) in enumerate(firsts.items()):
                recorder.write(topic, payload, log_time_ns=T + 1 + i)
            written = (await asyncio.to_thread(recorder.close)).written
            got = await client.messages(written)
            recorded = read_messages(tmp_path / "first.mcap").topic_counts
            assert collections.Counter(m.topic for m in got) == recorded
            assert {*firsts, "session/header", "/events"} <= set(recorded)
            assert not client.statuses
            await client.close()
        finally:
            server.close()

    asyncio.run(scenario())


def test_a_port_in_use_is_refused_in_one_line() -> None:
    first = LiveServer("127.0.0.1", 0, name="a")
    try:
        with pytest.raises(LiveServerError) as err:
            LiveServer("127.0.0.1", first.port, name="b")
        assert str(err.value) == (
            f"cannot start the Foxglove server on 127.0.0.1:{first.port}: Failed to bind port: "
            "Address already in use (os error 98)"
        )
    finally:
        first.close()


@pytest.mark.parametrize(
    ("value", "insecure", "result"),
    [
        ("127.0.0.1:8765", False, ("127.0.0.1", 8765)),
        ("localhost:0", False, ("localhost", 0)),
        ("[::1]:9000", False, ("::1", 9000)),
        ("0.0.0.0:8765", True, ("0.0.0.0", 8765)),
    ],
)
def test_loopback_addresses_are_served_and_others_only_when_insecure(
    value: str, insecure: bool, result: tuple[str, int]
) -> None:
    assert check_foxglove_listen(value, "foxglove.listen", insecure=insecure) == result


@pytest.mark.parametrize(
    ("value", "message"),
    [
        (
            "0.0.0.0:8765",
            "--foxglove: 0.0.0.0 is not a loopback address; the Foxglove server has no authentication, so it "
            "listens on 127.0.0.1 unless [foxglove] insecure = true",
        ),
        (
            "robot.local:8765",
            "--foxglove: robot.local is not a loopback address; the Foxglove server has no authentication, "
            "so it listens on 127.0.0.1 unless [foxglove] insecure = true",
        ),
        (
            "8765",
            "--foxglove: '8765' is not HOST:PORT like 127.0.0.1:8765 (IPv6 as [::1]:8765; port 0-65535)",
        ),
        (
            "h:70000",
            "--foxglove: 'h:70000' is not HOST:PORT like 127.0.0.1:8765 (IPv6 as [::1]:8765; port 0-65535)",
        ),
    ],
)
def test_run_refuses_a_bad_or_open_foxglove_address_with_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], value: str, message: str
) -> None:
    assert main(["run", "--sim", "--foxglove", value, "--record-dir", str(tmp_path)]) == 2
    assert capsys.readouterr().err.strip().splitlines()[-1] == f"dishbot run: error: {message}"
    assert list(tmp_path.iterdir()) == []


def test_the_config_refuses_an_open_address_unless_insecure() -> None:
    with pytest.raises(ConfigError) as err:
        load_config(overrides={"foxglove": {"listen": "192.168.1.5:8765"}})
    assert str(err.value).startswith("foxglove.listen: 192.168.1.5 is not a loopback address;")
    config = load_config(overrides={"foxglove": {"listen": "192.168.1.5:8765", "insecure": True}})
    assert config.foxglove.address == ("192.168.1.5", 8765)
    assert load_config().foxglove.address is None  # off by default
