"""The JSON Schema of every topic the daemon records, generated from the message declared for it
(``wire.messages``) rather than written by hand or guessed from a first message.

A channel's schema describes every message the channel will ever carry: each field dishbot writes, with its
type, unit and description (the field's ``doc``), ``required`` for the fields every message has, and fields a
later version adds allowed (``additionalProperties``). The ``kind`` of an event and the ``state`` are
enumerations: a new event kind goes into ``wire.messages.EVENT_KINDS`` (a test validates every message of a
recorded job against the schema stored with it).

Topics are matched by what follows ``dishbot/<robot_id>/``; a topic nobody declared a message for (a test's, a
tool's) gets a schema that says only "a JSON object".
"""

from __future__ import annotations

import functools
import json
from typing import Any, Final

import msgspec

from wire.messages import EVENT_KINDS, HEADER_TOPIC, TOPICS, Message, message_type, topic_suffix

JSON_SCHEMA_DIALECT: Final = "https://json-schema.org/draft/2020-12/schema"

Schema = dict[str, object]

# Telemetry the daemon publishes and reads many times a second; idle recordings keep it at a lower rate.
TELEMETRY_TOPICS: Final = frozenset({"joints", "gripper", "input/joints", "input/force", "input/holding"})


def _type_schema(info: Any) -> Schema:
    """The JSON Schema of one field's type, as msgspec describes it."""
    ins = msgspec.inspect
    if isinstance(info, ins.Metadata):
        return {**_type_schema(info.type), **(info.extra_json_schema or {})}
    if isinstance(info, ins.UnionType):
        members = [m for m in info.types if not isinstance(m, ins.NoneType)]
        nullable = len(members) < len(info.types)
        kinds = {type(m) for m in members}
        if kinds == {ins.IntType, ins.FloatType}:  # Number
            inner: Schema = {"type": "number"}
        elif len(members) == 1:
            inner = _type_schema(members[0])
        else:
            inner = {"anyOf": [_type_schema(m) for m in members]}
        if not nullable:
            return inner
        if isinstance(inner.get("type"), str):
            return {**inner, "type": [inner["type"], "null"]}
        return {"anyOf": [inner, {"type": "null"}]}
    if isinstance(info, ins.FloatType):
        return {"type": "number"}
    if isinstance(info, ins.BoolType):
        return {"type": "boolean"}
    if isinstance(info, ins.IntType):
        return {"type": "integer"}
    if isinstance(info, ins.StrType):
        return {"type": "string"}
    if isinstance(info, ins.LiteralType):
        return (
            {"const": info.values[0]}
            if len(info.values) == 1
            else {"type": "string", "enum": list(info.values)}
        )
    if isinstance(info, ins.ListType):
        return {"type": "array", "items": _type_schema(info.item_type)}
    if isinstance(info, ins.DictType):
        return {"type": "object"}
    if isinstance(info, ins.StructType):
        return _struct_schema(info)
    if isinstance(info, ins.AnyType):
        return {}
    raise TypeError(f"no JSON Schema for a field of type {info!r}")


def _struct_schema(info: Any) -> Schema:
    doc: Schema = {
        "type": "object",
        "properties": {f.encode_name: _type_schema(f.type) for f in info.fields},
        "additionalProperties": True,
    }
    required = [f.encode_name for f in info.fields if f.required]
    if required:
        doc["required"] = required
    return doc


@functools.cache
def message_schema(kind: type[Message]) -> Schema:
    """The JSON Schema of a declared message (without ``$schema`` and ``title``)."""
    return _struct_schema(msgspec.inspect.type_info(kind))


def schema_name(topic: str) -> str:
    """The schema's name as recorded: ``dishbot.<suffix>`` for dishbot's topics, else the topic."""
    if topic == HEADER_TOPIC:
        return "dishbot.session_header"
    suffix = topic_suffix(topic)
    return f"dishbot.{suffix.replace('/', '_')}" if suffix in TOPICS else topic


def schema_for(topic: str) -> Schema:
    """The JSON Schema of a recorded topic (a bare object schema for topics dishbot does not describe)."""
    kind = message_type(topic)
    body = {"type": "object"} if kind is None else message_schema(kind)
    return {"$schema": JSON_SCHEMA_DIALECT, "title": schema_name(topic), **body}


@functools.cache
def schema_bytes(topic: str) -> bytes:
    return json.dumps(schema_for(topic), separators=(",", ":"), ensure_ascii=False).encode()


def is_telemetry(topic: str) -> bool:
    """Whether a topic is high-rate telemetry (kept at a lower rate in idle recordings)."""
    return topic_suffix(topic) in TELEMETRY_TOPICS


def described_topics() -> tuple[str, ...]:
    """The topic suffixes a message is declared for."""
    return tuple(TOPICS)


__all__ = [
    "EVENT_KINDS",
    "HEADER_TOPIC",
    "JSON_SCHEMA_DIALECT",
    "TELEMETRY_TOPICS",
    "described_topics",
    "is_telemetry",
    "message_schema",
    "schema_bytes",
    "schema_for",
    "schema_name",
    "topic_suffix",
]
