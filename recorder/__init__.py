"""Session recording: MCAP files with every published message, the driver-boundary inputs, a header per
file and the Foxglove channels derived from them; tolerant reading of finished and cut files.

- ``writer``: ``Recorder``, the background-thread MCAP writer (crash-safe, rotating, with derived channels)
- ``reader``: ``read_messages``, record by record up to a cut; ``being_written``
- ``schemas``: the JSON Schema of every topic
- ``files``: which file a message goes to (a file per job, rotating idle files) and retention
- ``outcome``: what a job's events say happened (placed, given up and why, faults)
- ``plot``: one picture of a session (``dishbot record plot``)
"""

# The names below are loaded when first used (PEP 562), so that importing one light module of the package
# (``recorder.settings``, which the daemon's config reads) does not pull in the MCAP writer and reader.
from __future__ import annotations

import importlib
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from recorder.reader import (
        MCAP_MAGIC,
        RecordedMessage,
        RecordingRead,
        being_written,
        read_messages,
    )
    from recorder.writer import (
        COMPRESSIONS,
        MESSAGE_ENCODING,
        PROFILE,
        SCHEMA_ENCODING,
        ChannelSpec,
        Derived,
        Deriver,
        DiskSpace,
        Recorder,
        RecorderStats,
        Tee,
        header_payload,
        json_channel,
    )
    from wire.schemas import HEADER_TOPIC, schema_for

_HOME = {
    **dict.fromkeys(
        ("MCAP_MAGIC", "RecordedMessage", "RecordingRead", "being_written", "read_messages"),
        "recorder.reader",
    ),
    **dict.fromkeys(
        (
            "COMPRESSIONS",
            "MESSAGE_ENCODING",
            "PROFILE",
            "SCHEMA_ENCODING",
            "ChannelSpec",
            "Derived",
            "Deriver",
            "DiskSpace",
            "Recorder",
            "RecorderStats",
            "Tee",
            "header_payload",
            "json_channel",
        ),
        "recorder.writer",
    ),
    **dict.fromkeys(("HEADER_TOPIC", "schema_for"), "wire.schemas"),
}


def __getattr__(name: str) -> object:
    home = _HOME.get(name)
    if home is None:
        raise AttributeError(f"module 'recorder' has no attribute {name!r}")
    value = getattr(importlib.import_module(home), name)
    globals()[name] = value
    return value


__all__ = [
    "COMPRESSIONS",
    "HEADER_TOPIC",
    "MCAP_MAGIC",
    "MESSAGE_ENCODING",
    "PROFILE",
    "SCHEMA_ENCODING",
    "ChannelSpec",
    "Derived",
    "Deriver",
    "DiskSpace",
    "RecordedMessage",
    "Recorder",
    "RecorderStats",
    "RecordingRead",
    "Tee",
    "being_written",
    "header_payload",
    "json_channel",
    "read_messages",
    "schema_for",
]
