"""The wire contract: one declared message per topic. A recording made before the messages were declared
(tests/data/rig-2mugs-job.mcap) decodes with them, message by message, and encodes back to the same bytes; its
stored schemas and the generated ones both accept every message; the generated schema keeps every field,
type and requirement the stored one had. Anything else is refused with one line naming the field."""

from __future__ import annotations

import json
import logging
from collections import Counter
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import jsonschema
import msgspec
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from mcap.reader import make_reader

from wire.messages import (
    EVENT_KINDS,
    TOPICS,
    UNSET,
    BadMessage,
    Event,
    Gripper,
    HeaderClock,
    HeaderConfig,
    HeaderFile,
    HeaderJob,
    HeaderScene,
    Joints,
    Log,
    Message,
    Plan,
    State,
    decode,
    decode_topic,
    encode,
    header_part,
    message_type,
)
from wire.schemas import schema_for, schema_name

RECORDING = Path(__file__).parent.parent / "data" / "rig-2mugs-job.mcap"

# Open by nature: their producers write them as mappings, so a decoded one keeps its JSON value, not its key
# order (events), or only the fields declared for typed reading (log: a structlog call's own keys).
OPEN_ORDER = {"dishbot.events", "dishbot.input_device_event", "dishbot.session_header"}
OPEN_KEYS = {"dishbot.log"}


def _json_messages() -> Iterator[tuple[str, str, bytes, bytes]]:
    """(topic, schema name, schema data, message bytes) of every JSON message of the old recording."""
    with RECORDING.open("rb") as f:
        for schema, channel, message in make_reader(f).iter_messages():
            if channel.message_encoding == "json":
                assert schema is not None
                yield channel.topic, schema.name, schema.data, message.data


@pytest.fixture(scope="module")
def recorded() -> list[tuple[str, str, bytes, bytes]]:
    return list(_json_messages())


def test_a_recording_made_before_decodes_and_encodes_back_to_the_same_bytes(
    recorded: list[tuple[str, str, bytes, bytes]],
) -> None:
    seen: Counter[str] = Counter()
    for topic, name, _, data in recorded:
        kind = message_type(topic)
        assert kind is not None, topic
        assert schema_name(topic) == name
        message = decode_topic(topic, data)
        assert isinstance(message, kind)
        again = encode(message)
        if name in OPEN_KEYS:
            doc = json.loads(data)
            assert json.loads(again) == {k: v for k, v in doc.items() if k in json.loads(again)}
            assert set(json.loads(again)) == set(doc) & set(kind.__struct_fields__)
        elif name in OPEN_ORDER:
            assert json.loads(again) == json.loads(data), (topic, data)
        else:
            assert again == data, (topic, data, again)
        seen[name] += 1
    # every kind of message the recording has was seen (and so checked)
    assert len(seen) == 16
    assert seen["dishbot.events"] == 41


def test_the_stored_schemas_and_the_generated_ones_accept_every_recorded_message(
    recorded: list[tuple[str, str, bytes, bytes]],
) -> None:
    validators: dict[str, tuple[Any, Any]] = {}
    for topic, name, stored, data in recorded:
        if name not in validators:
            old, new = json.loads(stored), schema_for(topic)
            jsonschema.Draft202012Validator.check_schema(new)
            validators[name] = (jsonschema.Draft202012Validator(old), jsonschema.Draft202012Validator(new))
        doc = json.loads(data)
        for validator in validators[name]:
            validator.validate(doc)
        # and what a decoded message encodes to (events: every kind, every field it had)
        for validator in validators[name]:
            validator.validate(json.loads(encode(decode_topic(topic, data))))


def test_the_generated_schema_keeps_the_stored_schemas_names_fields_types_and_requirements(
    recorded: list[tuple[str, str, bytes, bytes]],
) -> None:
    stored = {topic: json.loads(s) for topic, _, s, _ in recorded}
    for topic, old in stored.items():
        new: dict[str, Any] = schema_for(topic)
        assert new["title"] == old["title"] == schema_name(topic)
        assert new["$schema"] == old["$schema"]
        assert new.get("required") == old.get("required"), topic
        assert new["additionalProperties"] is True
        for field, was in old["properties"].items():
            now = new["properties"][field]
            assert now.get("type") == was.get("type"), (topic, field)
            assert now.get("items", {}).get("type") == was.get("items", {}).get("type"), (topic, field)
            assert set(was.get("enum", ())) <= set(now.get("enum", ())), (topic, field)


def test_the_header_views_read_every_recorded_header_clock_and_job(caplog: pytest.LogCaptureFixture) -> None:
    """The views replay/ reads the header through take what each recorded header holds (an empty view
    would silently read as "missing")."""
    caplog.set_level(logging.WARNING, logger="wire.messages")
    headers = []
    for path in sorted(RECORDING.parent.glob("*.mcap")):
        with path.open("rb") as f:
            for _, _channel, message in make_reader(f).iter_messages(topics=["session/header"]):
                headers.append((path.name, json.loads(message.data)))
    assert headers
    for name, header in headers:
        clock = header_part(header.get("clock"), HeaderClock)
        assert clock.source in ("wall", "simulated"), name
        assert isinstance(clock.wall_start, int | float), name
        scene = header.get("scene")
        assert header_part(scene, HeaderScene).dataset == scene.get("dataset", UNSET), name
        assert header_part(scene, HeaderScene).backend == scene["backend"], name
        job = header.get("job")
        if isinstance(job, dict):
            view = header_part(job, HeaderJob)
            assert view.sim_seed == job.get("sim_seed", view.sim_seed), name
            assert (view.mugs is None) == (job.get("mugs") is None), name
        header_part(header.get("file"), HeaderFile)
        header_part(header.get("config"), HeaderConfig)
    assert [r.getMessage() for r in caplog.records] == []


def test_a_carried_job_header_keeps_its_view_and_a_malformed_clock_is_an_empty_one() -> None:
    job: dict[str, object] = {
        "dataset": None,
        "mugs": None,
        "sim_seed": 4,
        "carried": {"on_tray": [], "counter": []},
    }
    assert header_part(job, HeaderJob).sim_seed == 4
    assert header_part(job, HeaderJob).carried == {"on_tray": [], "counter": []}
    assert header_part({"source": "simulated", "wall_start": "soon"}, HeaderClock) == HeaderClock()


def test_a_header_document_that_does_not_fit_its_view_is_logged_not_silent(
    caplog: pytest.LogCaptureFixture,
) -> None:
    caplog.set_level(logging.WARNING, logger="wire.messages")
    assert header_part({"source": "simulated", "wall_start": "soon"}, HeaderClock) == HeaderClock()
    assert header_part(["a", "list"], HeaderScene) == HeaderScene()
    assert header_part(None, HeaderJob) == HeaderJob()  # missing: not a warning
    messages = [r.getMessage() for r in caplog.records]
    assert len(messages) == 2, messages
    assert "HeaderClock does not fit" in messages[0], messages
    assert "wall_start" in messages[0], messages
    assert "HeaderScene is a list, not a table" in messages[1], messages


def test_every_topic_has_a_schema_named_after_it() -> None:
    names = {schema_name(f"dishbot/r1/{t}") for t in TOPICS}
    assert len(names) == len(TOPICS)
    assert schema_name("dishbot/r1/input/joints") == "dishbot.input_joints"
    assert schema_name("session/header") == "dishbot.session_header"
    assert schema_for("dishbot/r1/other")["title"] == "dishbot/r1/other"


def test_the_readme_event_kinds_are_declared() -> None:
    readme = (Path(__file__).parents[2] / "README.md").read_text()
    for kind in ("servo_warning", "servo_health_ok", "servo_fault", "fault_injected", "fault_ended"):
        assert f"`{kind}`" in readme
        assert kind in EVENT_KINDS
    properties = schema_for("dishbot/r1/events")["properties"]
    assert isinstance(properties, dict)
    assert "servo_warning" in properties["kind"]["enum"]
    assert "servo_health_ok" in properties["kind"]["enum"]


@pytest.mark.parametrize(
    ("data", "kind", "said"),
    [
        (b'{"state":"idle","mugs_total":0,"mugs_placed":0}', State, "state: t: missing"),
        (
            b'{"state":"idle","mugs_total":"2","mugs_placed":0,"t":1}',
            State,
            "state: mugs_total: expected `int`",
        ),
        (
            b'{"t":1,"names":["a"],"position_rad":[0.1,"x"]}',
            Joints,
            "joints: position_rad[1]: expected `int | float`",
        ),
        (b'{"t":1,"aperture_m":0.09,"holding":1}', Gripper, "gripper: holding: expected `bool`, got `int`"),
        (b'{"t":1,', Gripper, "gripper: not JSON: Input data was truncated"),
        (b"[]", Event, "events: expected `object`, got `array`"),
        (b'{"slots":[{"id":"m1"}]}', Plan, "plan: slots[0].type: missing"),
    ],
)
def test_a_malformed_payload_is_refused_with_one_line_naming_the_field(
    data: bytes, kind: type[Message], said: str
) -> None:
    topic = next(t for t, k in TOPICS.items() if k is kind)
    with pytest.raises(BadMessage) as e:
        decode(data, kind, name=topic)
    assert str(e.value).startswith(said)
    assert "\n" not in str(e.value)
    with pytest.raises(BadMessage, match="no message is declared"):
        decode_topic("dishbot/r1/unknown", b"{}")


def test_a_message_encodes_in_declared_order_leaving_out_what_it_does_not_carry() -> None:
    state = State(state="idle", mugs_total=2, mugs_placed=0, current_mug=None, t=1.5)
    assert encode(state) == b'{"state":"idle","mugs_total":2,"mugs_placed":0,"current_mug":null,"t":1.5}'
    assert decode(encode(state), State) == state
    log = decode(b'{"path":"x.mcap","event":"recording_started","level":"info","t":3}', Log)
    assert (log.event, log.level, log.t) == ("recording_started", "info", 3)


def test_the_encoder_writes_numpy_scalars_as_numbers_and_refuses_what_json_cannot_hold() -> None:
    assert encode({"a": np.float64(0.5), "b": np.int64(3), "c": Path("x")}) == b'{"a":0.5,"b":3,"c":"x"}'
    assert encode({"b": np.bool_(True), "f": np.float32(0.5), "t": (2, 3)}) == b'{"b":true,"f":0.5,"t":[2,3]}'
    with pytest.raises(TypeError, match="Object of type ndarray is not JSON serializable"):
        encode({"a": np.array([1.0, 2.0])})
    with pytest.raises(ValueError, match="Out of range float"):
        encode({"a": None, "b": [1.0, float("nan")]})
    with pytest.raises(ValueError, match="Out of range float"):
        encode(Joints(t=1.0, names=["a"], position_rad=[float("inf")], load=[]))


finite = st.floats(allow_nan=False, allow_infinity=False)


@given(
    state=st.sampled_from(["idle", "detect", "done"]),
    total=st.integers(0, 50),
    placed=st.integers(0, 50),
    current=st.none() | st.text(max_size=8),
    t=finite,
)
def test_any_state_round_trips_and_the_stdlib_reads_the_same_value(
    state: str, total: int, placed: int, current: str | None, t: float
) -> None:
    message = State(state=state, mugs_total=total, mugs_placed=placed, current_mug=current, t=t)
    data = encode(message)
    assert decode(data, State) == message
    assert json.loads(data) == msgspec.to_builtins(message)
