"""A driver's fault as published on ``events``: JSON values, lists as lists (not their Python text)."""

from __future__ import annotations

import json
from pathlib import Path

from daemon.messages import device_event_payload
from drivers.dynamixel.bus import DeviceEvent


def test_a_servo_faults_bits_are_a_json_list_of_names() -> None:
    event = DeviceEvent(
        "servo_fault", "servo/6", 1.5, {"servo_id": 6, "reason": "overload", "faults": ["overload"]}
    )
    payload = device_event_payload(event, t=2.0)
    assert payload == {
        "servo_id": 6,
        "reason": "overload",
        "faults": ["overload"],
        "kind": "servo_fault",
        "device": "servo/6",
        "t": 2.0,
        "t_device": 1.5,
    }
    assert json.loads(json.dumps(payload))["faults"] == ["overload"]


def test_values_json_cannot_carry_become_their_text() -> None:
    detail: dict[str, object] = {
        "port": Path("/dev/ttyUSB0"),
        "ids": (1, 2),
        "mixed": [1, object],
        "none": None,
    }
    payload = device_event_payload(DeviceEvent("bus_lost", "bus", 0.0, detail), t=0.0)
    assert payload["port"] == "/dev/ttyUSB0"
    assert payload["ids"] == [1, 2]
    assert isinstance(payload["mixed"], str)
    assert payload["none"] is None
    json.dumps(payload)  # all of it is JSON
