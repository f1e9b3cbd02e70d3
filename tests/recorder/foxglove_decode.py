"""Decoding the Foxglove channels of a recording with the schemas stored in it, as Foxglove itself does.

Protobuf channels are decoded with the ``FileDescriptorSet`` in their schema record (google.protobuf, not the
Foxglove SDK that wrote them); JSON channels are parsed and checked against their stored JSON Schema.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import jsonschema
from google.protobuf import descriptor_pb2, descriptor_pool, message_factory
from mcap.reader import make_reader


@dataclass(frozen=True)
class Decoded:
    topic: str
    schema_name: str
    log_time_ns: int
    message: Any  # a protobuf message or a JSON object


def message_class(name: str, data: bytes) -> Any:
    files = descriptor_pb2.FileDescriptorSet.FromString(data)
    pool = descriptor_pool.DescriptorPool()
    for file in files.file:
        pool.Add(file)
    return message_factory.GetMessageClass(pool.FindMessageTypeByName(name))


def decode_all(path: Path) -> Iterator[Decoded]:
    """Every message of a finished recording, decoded with its stored schema (JSON ones validated)."""
    classes: dict[int, Any] = {}
    validators: dict[int, Any] = {}
    with path.open("rb") as f:
        for schema, channel, message in make_reader(f).iter_messages(log_time_order=False):
            assert schema is not None, channel.topic
            if channel.message_encoding == "protobuf":
                assert schema.encoding == "protobuf"
                if schema.id not in classes:
                    classes[schema.id] = message_class(schema.name, schema.data)
                yield Decoded(
                    channel.topic, schema.name, message.log_time, classes[schema.id].FromString(message.data)
                )
            else:
                assert (channel.message_encoding, schema.encoding) == ("json", "jsonschema")
                if schema.id not in validators:
                    document = json.loads(schema.data)
                    jsonschema.Draft202012Validator.check_schema(document)
                    validators[schema.id] = jsonschema.Draft202012Validator(document)
                payload = json.loads(message.data)
                validators[schema.id].validate(payload)
                yield Decoded(channel.topic, schema.name, message.log_time, payload)
