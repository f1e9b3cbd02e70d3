"""Session recording: MCAP files with every published message, the driver-boundary inputs, a header per
file and the Foxglove channels derived from them; tolerant reading of finished and cut files.

- ``writer``: ``Recorder``, the background-thread MCAP writer (crash-safe, rotating, with derived channels)
- ``reader``: ``read_messages``, record by record up to a cut; ``being_written``
- ``schemas``: the JSON Schema of every topic
- ``files``: which file a message goes to (a file per job, rotating idle files) and retention
- ``outcome``: what a job's events say happened (placed, given up and why, faults)
- ``plot``: one picture of a session (``dishbot record plot``)
"""

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
