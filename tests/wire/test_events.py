"""The job's events by kind (``wire.messages.JobEvents``, a tagged union on ``kind``): each writes the bytes
the job wrote as a mapping before (``kind``, the state, the times, then the detail in the job's order);
every field of every kind is a field of the flat ``Event`` (the topic's schema) of the same type;
``decode_event`` reads a kind's event as its struct and anything else (a transition, a device's event, an
unknown kind) as ``Event``."""

from __future__ import annotations

from typing import Any

import msgspec
import pytest

from wire.messages import (
    EVENT_KINDS,
    JOB_EVENTS,
    UNSET,
    CounterChangedEvent,
    CyclePlannedEvent,
    Event,
    FaultEvent,
    GraspFailedEvent,
    JobEvent,
    MugPlacedEvent,
    MugSwappedEvent,
    RecordingFailedEvent,
    decode_event,
    encode,
)

STAMP = {"state": "pick.grasp", "t": 1796444156.25, "t_device": 12.5}


def _old(kind: str, **detail: Any) -> dict[str, Any]:
    """``Services.event`` as it was: the kind, the state, the times, then the detail as the call named it."""
    return {"kind": kind, **STAMP, **detail}


def _stamped(event: JobEvent) -> JobEvent:
    state = STAMP["state"] if event.state is UNSET else event.state
    return msgspec.structs.replace(event, state=state, t=STAMP["t"], t_device=STAMP["t_device"])


@pytest.mark.parametrize(
    ("new", "old"),
    [
        (
            MugSwappedEvent(slot_for="m2", mug_id="m5", reason="blocked or out of reach"),
            _old("mug_swapped", slot_for="m2", mug_id="m5", reason="blocked or out of reach"),
        ),
        (
            CyclePlannedEvent(mug_id="m1", retry=False, duration_s=25.6, energy_j=130),
            _old("cycle_planned", mug_id="m1", retry=False, duration_s=25.6, energy_j=130),
        ),
        (
            MugPlacedEvent(mug_id="m1", x_m=0.31, y_m=-0.1, handle_yaw_rad=1.5708),
            _old("mug_placed", mug_id="m1", x_m=0.31, y_m=-0.1, handle_yaw_rad=1.5708),
        ),
        (
            MugPlacedEvent(mug_id="m1", x_m=0.31, y_m=-0.1),
            _old("mug_placed", mug_id="m1", x_m=0.31, y_m=-0.1),
        ),
        (
            GraspFailedEvent(state="pick.verify", mug_id="m3"),
            {**_old("grasp_failed", mug_id="m3"), "state": "pick.verify"},
        ),
        (CounterChangedEvent(came=["m9"], went=[]), _old("counter_changed", came=["m9"], went=[])),
        (
            RecordingFailedEvent(path="/rec/a.mcap", error="disk full", dropped=7),
            _old("recording_failed", path="/rec/a.mcap", error="disk full", dropped=7),
        ),
        (FaultEvent(reason="BusLost: gone"), _old("fault", reason="BusLost: gone")),
    ],
    ids=lambda v: v.__struct_config__.tag if isinstance(v, JobEvent) else "",
)
def test_a_kind_writes_the_bytes_the_job_wrote(new: JobEvent, old: dict[str, Any]) -> None:
    assert encode(_stamped(new)) == encode(old)
    assert decode_event(encode(old)) == _stamped(new)


def test_every_kind_field_is_an_event_field_of_the_same_type() -> None:
    flat = {f.name: f.type for f in _fields(Event)}
    for kind in JOB_EVENTS:
        tag = kind.__struct_config__.tag
        assert tag in EVENT_KINDS
        for f in _fields(kind):
            assert f.name in flat, f"{tag}: {f.name} is not a field of Event"
            want = _bare(flat[f.name])
            assert _bare(f.type) == want, f"{tag}: {f.name} is {f.type}, Event's {want}"


def _fields(kind: type[msgspec.Struct]) -> tuple[msgspec.inspect.Field, ...]:
    info = msgspec.inspect.type_info(kind)
    assert isinstance(info, msgspec.inspect.StructType)
    return info.fields


def _bare(t: msgspec.inspect.Type) -> msgspec.inspect.Type:
    """A field's type without its description (``doc``)."""
    if isinstance(t, msgspec.inspect.Metadata):
        return _bare(t.type)
    if isinstance(t, msgspec.inspect.UnionType):
        return msgspec.inspect.UnionType(tuple(_bare(x) for x in t.types))
    if isinstance(t, msgspec.inspect.ListType):
        return msgspec.inspect.ListType(_bare(t.item_type))
    return t


@pytest.mark.parametrize(
    "payload",
    [
        {
            "kind": "transition",
            "state": "idle",
            "t": 1.0,
            "trigger": "start",
            "source": "idle",
            "dest": "detect",
        },
        {"port": "/dev/ttyUSB0", "kind": "bus_lost", "device": "servo bus", "t": 2.0, "t_device": 1.5},
        {"kind": "a_kind_from_a_later_version", "t": 3.0, "whatever": [1, 2]},
        {"kind": "mug_placed", "t": 4.0},  # a kind's event without its fields (an older recording)
    ],
    ids=["transition", "device event", "unknown kind", "older"],
)
def test_any_other_event_reads_as_the_flat_event(payload: dict[str, Any]) -> None:
    event = decode_event(encode(payload))
    assert type(event) is Event
    assert event.kind == payload["kind"]
