"""The replay's session reads its payloads through the wire contract: a device command recorded and one asked
now are one typed value, and an older recording's device events are rebuilt as the declared
``input/device_event`` and anchored where the newer recording says they came."""

from __future__ import annotations

from pathlib import Path

import pytest

from replay.session import DeviceCommand, RecordedSession, device_command
from tests.replay.conftest import copy_recording
from wire.messages import (
    BadMessage,
    CloseAsked,
    DeviceEventInput,
    Follow,
    FollowAsked,
    Grasp,
    GripperCommand,
    InputPosition,
    OpenAsked,
    Started,
    UnsetType,
    convert,
    view,
)

DATA = Path(__file__).parent.parent / "data"
DEVICE_EVENT_RECORDINGS = (
    "rig-fault-while-packing-job.mcap",
    "rig-fault-while-planning-job.mcap",
    "rig-fault-while-probing-job.mcap",
    "rig-gripper-failed-while-planning-job.mcap",
)
# What a recording of the older format lacked (``test_replay_faithful``'s older recorder).
NEWER_TOPICS = (
    "input/device_event",
    "input/motion",
    "input/gripper",
    "input/gripper_failed",
    "input/joints_failed",
    "input/health_failed",
)


def test_every_recorded_device_command_reads_as_the_request_the_drivers_make_now() -> None:
    """Each recorded follow, opening and close gives the same command as the request a replay's driver
    builds for it (its fields only), as a mapping and as the view itself."""
    session = RecordedSession.load(DATA / "rig-2mugs-job.mcap")
    seen = 0
    for suffix, records in session.streams.items():
        for r in records:
            message = r.message
            request: dict[str, object]
            asked: FollowAsked | OpenAsked | CloseAsked
            if isinstance(message, Follow):
                end = [] if isinstance(message.end_rad, UnsetType) else [float(v) for v in message.end_rad]
                request = {"label": message.label, "end_rad": end}
                asked = FollowAsked(label=message.label, end_rad=end)
            elif isinstance(message, GripperCommand) and message.action == "open":
                aperture = None if isinstance(message.aperture_m, UnsetType) else message.aperture_m
                request, asked = (
                    {"action": "open", "aperture_m": aperture},
                    OpenAsked(action="open", aperture_m=aperture),
                )
            elif isinstance(message, Grasp) and not isinstance(message.force_threshold_n, UnsetType):
                threshold = message.force_threshold_n
                request, asked = {"force_threshold_n": threshold}, CloseAsked(force_threshold_n=threshold)
            else:
                continue
            seen += 1
            recorded = device_command(suffix, r.payload, 1.5)
            assert recorded is not None
            assert device_command(suffix, request, 1.5) == recorded
            assert device_command(suffix, asked, 1.5) == recorded
    assert seen > 20  # 38 moves, the openings and the closes of a two-mug job


def test_device_commands_the_contract_does_not_hold() -> None:
    assert device_command("output/gripper", {"action": "stop"}, 0.0) is None
    assert device_command("output/gripper", {"action": "open", "aperture_m": None}, 2.0) == DeviceCommand(
        "open", "", (), 2.0
    )
    assert device_command("input/grasp_failed", {"t_start": 1.0, "t_end": 2.0}, 0.0) == DeviceCommand(
        "close", "", (), 0.0
    )
    # Not a command: no label, a goal that is not numbers, a threshold in words.
    assert device_command("output/follow", {"end_rad": [0.1]}, 0.0) is None
    assert device_command("output/follow", {"label": "lift", "end_rad": ["0.1"]}, 0.0) is None
    assert device_command("input/grasp", {"force_threshold_n": "hard"}, 0.0) is None
    assert device_command("input/joints", {"label": "lift"}, 0.0) is None


def test_a_view_names_what_is_wrong_in_one_line() -> None:
    with pytest.raises(
        BadMessage, match=r"^output/follow: end_rad\[0\]: expected `int \| float`, got `str`$"
    ):
        view({"label": "lift", "end_rad": ["x"]}, FollowAsked, name="output/follow")
    with pytest.raises(BadMessage, match="at_transitions: expected `int`, got `bool`"):
        view({"at_transitions": True}, InputPosition)
    assert view({"t_start": 3, "label": "x"}, Started).t_start == 3


@pytest.mark.parametrize("name", DEVICE_EVENT_RECORDINGS)
def test_an_older_recordings_device_events_are_rebuilt_as_the_declared_input(
    name: str, tmp_path: Path
) -> None:
    """Without ``input/device_event`` a session takes the device events from ``events``: each is rebuilt as
    the declared ``input/device_event``, as the driver handed it, and falls after the same transitions and
    device commands as the newer recording says it did (its time after them within 0.05 s: it is placed
    by time)."""

    def older(topic: str, payload: dict[str, object]) -> dict[str, object] | None:
        if topic in NEWER_TOPICS:
            return None
        return {k: v for k, v in payload.items() if not k.startswith(("at_", "error_"))}

    newer = RecordedSession.load(DATA / name)
    old = RecordedSession.load(copy_recording(DATA / name, tmp_path / f"old-{name}", older))
    assert "input/device_event" not in old.streams
    assert len(old.device_events) == len(newer.device_events) > 0
    for rebuilt, recorded in zip(old.device_events, newer.device_events, strict=True):
        event = convert(rebuilt.payload, DeviceEventInput, name="input/device_event")
        assert event.kind == recorded.payload["kind"]
        assert old.device_event_payload(rebuilt) == newer.device_event_payload(recorded)
        a, b = old.anchor(rebuilt), newer.anchor(recorded)
        assert (a.transitions, a.device_commands) == (b.transitions, b.device_commands)
        assert a.after_s == pytest.approx(b.after_s, abs=0.05)


def test_an_input_whose_position_is_not_one_is_placed_by_its_time() -> None:
    """A recorded position that is not the declared one (a flag where a count goes) is not taken: the
    input is placed by its read time, as one recorded without a position is."""
    session = RecordedSession.load(DATA / "rig-fault-while-packing-job.mcap")
    r = session.device_events[-1]
    bare = {k: v for k, v in r.payload.items() if not k.startswith("at_")}
    bent = {**bare, "at_transitions": True, "at_device_commands": 1}
    as_recorded = type(r)(r.kind, r.t_ns, bare)
    assert session.anchor(type(r)(r.kind, r.t_ns, bent)) == session.anchor(as_recorded)
    assert session.monotonic_of(as_recorded) == r.payload["t_read"]
