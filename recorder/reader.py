"""Reading recordings, finished or not: record by record, up to the first byte that cannot be used.

A file whose writer never called ``finish()`` (crash, ``kill -9``, a partial copy, a file still being
written) cannot be opened by MCAP's indexed reader. ``read_messages`` walks the records instead and stops
cleanly where the file ends (or turns corrupt), reporting the byte and the time of the cut. Finished files
are read the same way, so there is one code path for both. Whether an unfinished file is still being written
is told by the writer's ``flock`` on it: a live writer holds it, a crashed one released it with its process.
"""

from __future__ import annotations

import contextlib
import fcntl
import io
import json
import mmap
import os
import struct
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Final, TypeVar

import msgspec
from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, Footer, Header, Schema
from mcap.stream_reader import get_chunk_data_stream

from recorder.errors import RecordingError
from recorder.writer import MESSAGE_ENCODING
from wire.messages import BadMessage, Message, convert, decode, topic_suffix
from wire.schemas import HEADER_TOPIC

M = TypeVar("M", bound=Message)

MCAP_MAGIC: Final = b"\x89MCAP0\r\n"

_RECORD_PREFIX = struct.Struct("<BQ")  # opcode, record length
_MESSAGE_PREFIX = struct.Struct("<HIQQ")  # channel id, sequence, log time, publish time; then the data


class _AnyObject(msgspec.Struct):
    """Any JSON object: decoding into it checks the bytes are one, skipping its values (nothing is built)."""


_CHECK: Final = msgspec.json.Decoder(_AnyObject)
_DECODE: Final = msgspec.json.Decoder()


def json_object(raw: bytes) -> dict[str, object]:
    """A payload's JSON bytes decoded (msgspec's decoder, a few times quicker than ``json``'s; ``json``'s for
    what only it reads, the ``NaN`` and ``Infinity`` an older writer let through). ``ValueError`` when they
    are not JSON; the value is a dict when they passed ``is_json_object``."""
    try:
        value: dict[str, object] = _DECODE.decode(raw)
    except msgspec.DecodeError:
        value = json.loads(raw)
    return value


def is_json_object(raw: bytes) -> bool:
    """Whether ``raw`` is one JSON object, checked without building it; ``ValueError`` when it is not JSON."""
    try:
        _CHECK.decode(raw)
    except msgspec.ValidationError:
        return False  # (JSON, but not an object)
    except msgspec.DecodeError:
        return isinstance(json.loads(raw), dict)  # (or what only ``json`` reads)
    return True


def decoded_as(raw: bytes, kind: type[M], *, name: str = "") -> M:
    """A payload's JSON bytes as the message ``kind``, decoded straight into it (no dict between); what only
    ``json`` reads goes through a dict. ``BadMessage`` when it is not one (``ValueError`` when not JSON)."""
    try:
        return decode(raw, kind, name=name)
    except BadMessage:
        try:
            _DECODE.decode(raw)
        except msgspec.DecodeError:
            return convert(json.loads(raw), kind, name=name)
        raise


class RecordedMessage:
    """One message as recorded: its topic (key expression), log time and decoded JSON payload.

    Read compactly (``read_messages(..., compact=True)``) it keeps the payload's JSON bytes as recorded
    (``raw``) and decodes them at each ``payload``: a long recording's messages then take about their size
    in the file, not several times it as Python dicts. Immutable either way."""

    __slots__ = ("_data", "log_time_ns", "topic")

    topic: str
    log_time_ns: int
    _data: dict[str, object] | bytes  # the payload, or its JSON bytes

    def __init__(
        self,
        topic: str,
        log_time_ns: int,
        payload: dict[str, object] | None = None,
        *,
        raw: bytes | None = None,
    ) -> None:
        data = payload if payload is not None else raw
        if data is None or (payload is not None and raw is not None):
            raise TypeError("a RecordedMessage holds either its payload or its raw JSON bytes")
        object.__setattr__(self, "topic", topic)
        object.__setattr__(self, "log_time_ns", log_time_ns)
        object.__setattr__(self, "_data", data)

    def __setattr__(self, name: str, value: object) -> None:
        raise AttributeError(f"RecordedMessage is immutable (cannot set {name})")

    def __delattr__(self, name: str) -> None:
        raise AttributeError(f"RecordedMessage is immutable (cannot delete {name})")

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, RecordedMessage):
            return NotImplemented
        return (self.topic, self.log_time_ns, self.payload) == (other.topic, other.log_time_ns, other.payload)

    __hash__ = None  # type: ignore[assignment]  # (a payload is a dict)

    def __repr__(self) -> str:
        return (
            f"RecordedMessage(topic={self.topic!r}, log_time_ns={self.log_time_ns!r}, "
            f"payload={self.payload!r})"
        )

    @property
    def payload(self) -> dict[str, object]:
        """The payload, a JSON object (read compactly: decoded anew at each call, a fresh dict)."""
        data = self._data
        if isinstance(data, dict):
            return data
        return json_object(data)

    @property
    def raw(self) -> bytes | None:
        """The payload's JSON bytes as recorded, when read compactly (else None)."""
        data = self._data
        return data if isinstance(data, bytes) else None

    def decoded(self, kind: type[M]) -> M | None:
        """The payload as the declared message ``kind`` (``wire.messages``); None when it is not one (a
        malformed message, which readers of a recording leave out rather than stop at). Read compactly, the
        bytes are decoded straight into ``kind``."""
        data = self._data
        try:
            if isinstance(data, bytes):
                return decoded_as(data, kind, name=topic_suffix(self.topic))
            return convert(data, kind, name=topic_suffix(self.topic))
        except BadMessage:
            return None


@dataclass(frozen=True, slots=True)
class RecordingRead:
    """Everything recovered from a recording, in file order, and whether (and where) the file was cut.

    ``truncated`` is True when the file does not end with a footer and the closing magic (the writer was
    killed, the disk filled, the file was copied partway, or it is still being written) or a record turned
    out corrupt. ``being_written`` tells the last case: a live recorder holds the file's lock.
    ``cut_at_byte`` is the offset of the first byte that could not be used; ``cut_after_ns`` the log time of
    the last message recovered before it (None when nothing was). ``cut_reason`` says why reading stopped.
    ``topic_counts``, ``start_ns`` and ``end_ns`` cover every recovered message, also those not kept (and
    those of non-JSON channels, which are counted but never decoded). ``schemas`` has the JSON Schema of
    each JSON channel, ``schema_names`` the schema name of every channel (``foxglove.FrameTransforms``).
    """

    path: Path
    messages: tuple[RecordedMessage, ...]
    topic_counts: Mapping[str, int]
    start_ns: int | None
    end_ns: int | None
    size_bytes: int
    truncated: bool
    cut_at_byte: int | None
    cut_after_ns: int | None
    cut_reason: str = ""
    library: str = ""
    schemas: Mapping[str, object] = field(default_factory=dict)
    schema_names: Mapping[str, str] = field(default_factory=dict)
    being_written: bool = False

    def __iter__(self) -> Iterator[RecordedMessage]:
        return iter(self.messages)

    def __len__(self) -> int:
        return len(self.messages)

    @property
    def message_count(self) -> int:
        return sum(self.topic_counts.values())

    @property
    def header(self) -> dict[str, object] | None:
        """The session header payload (``config`` and ``scene``, for a job file ``job``), or None when none
        was kept or recorded."""
        return next((m.payload for m in self.messages if m.topic == HEADER_TOPIC), None)


def read_messages(
    path: Path, *, keep: Callable[[str], bool] | None = None, compact: bool = False
) -> RecordingRead:
    """Read a recording, finished or not, up to the first byte that cannot be used.

    ``keep(topic)`` selects the topics whose payloads are decoded and returned (default: all JSON topics);
    the others are only counted (never decoded), which keeps summaries of long sessions cheap. With
    ``compact`` the kept messages hold their JSON bytes, not the decoded dicts (``RecordedMessage.raw``):
    each is still checked here to be a JSON object, without building it. Raises ``RecordingError``
    (one line, naming the file) when the file is missing, empty or not MCAP, or a message in an intact chunk
    is not a JSON object.
    """
    path = Path(path)
    try:
        with open(path, "rb") as f:
            size = os.fstat(f.fileno()).st_size
            if size == 0:
                raise RecordingError(f"{path}: empty file, not a recording")
            with mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as data:
                head = data[: len(MCAP_MAGIC)]
                if head != MCAP_MAGIC:
                    if MCAP_MAGIC.startswith(head):
                        raise RecordingError(
                            f"{path}: cut inside the MCAP magic after {size} bytes, nothing recorded"
                        )
                    raise RecordingError(f"{path}: not an MCAP file (bad magic)")
                read = _Scan(path, data, keep, compact=compact).run()
            if read.truncated and _locked(f.fileno()):
                read = _with_writer(read)
            return read
    except FileNotFoundError as e:
        raise RecordingError(f"{path}: no such file") from e
    except IsADirectoryError as e:
        raise RecordingError(f"{path}: is a directory, not a recording file") from e
    except PermissionError as e:
        raise RecordingError(f"{path}: permission denied") from e


def being_written(path: Path) -> bool:
    """Whether a live recorder holds ``path`` open for writing (its ``flock``); False when it cannot tell."""
    try:
        with open(path, "rb") as f:
            return _locked(f.fileno())
    except OSError:
        return False


def _locked(fd: int) -> bool:
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
    except BlockingIOError:
        return True
    except OSError:  # a file system without locks: nobody can be seen writing
        return False
    fcntl.flock(fd, fcntl.LOCK_UN)
    return False


def _with_writer(read: RecordingRead) -> RecordingRead:
    return RecordingRead(
        **{name: getattr(read, name) for name in read.__dataclass_fields__ if name != "being_written"},
        being_written=True,
    )


class _Scan:
    """One pass over the records of a mapped file, tolerant of a missing end."""

    def __init__(
        self, path: Path, data: mmap.mmap, keep: Callable[[str], bool] | None, *, compact: bool = False
    ) -> None:
        self.path = path
        self.data = data
        self.keep = keep
        self.compact = compact
        self.topics: dict[int, str] = {}
        self.kept: dict[int, bool] = {}
        self.schemas: dict[int, Schema] = {}
        self.schema_docs: dict[str, object] = {}
        self.schema_names: dict[str, str] = {}
        self.counts: dict[str, int] = {}
        self.start_ns: int | None = None
        self.end_ns: int | None = None
        self.messages: list[RecordedMessage] = []
        self.library = ""

    def run(self) -> RecordingRead:
        pos = len(MCAP_MAGIC)
        end = len(self.data)
        while True:
            if pos + _RECORD_PREFIX.size > end:
                return self._done(
                    pos, "file ends before the footer" if pos == end else "file ends mid-record"
                )
            opcode, length = _RECORD_PREFIX.unpack_from(self.data, pos)
            body_start = pos + _RECORD_PREFIX.size
            if length > end - body_start:
                return self._done(pos, "file ends mid-record")
            try:
                self._record(opcode, self.data[body_start : body_start + length], pos)
            except RecordingError:
                raise
            except Exception as e:  # any decoding failure of an intact-length record: corrupt from here on
                return self._done(pos, f"corrupt {_opcode_name(opcode)} record ({e})")
            pos = body_start + length
            if opcode == Opcode.FOOTER:
                if self.data[pos:] == MCAP_MAGIC:
                    return self._done(None, "")
                return self._done(pos, "file ends inside the closing magic")

    def _record(self, opcode: int, body: bytes, offset: int) -> None:
        stream = ReadDataStream(io.BytesIO(body))
        if opcode == Opcode.HEADER:
            self.library = Header.read(stream).library
        elif opcode == Opcode.SCHEMA:
            self._schema(Schema.read(stream))
        elif opcode == Opcode.CHANNEL:
            self._channel(Channel.read(stream))
        elif opcode == Opcode.MESSAGE:
            self._message(body, 0, len(body), offset)
        elif opcode == Opcode.CHUNK:
            chunk_stream, size = get_chunk_data_stream(Chunk.read(stream), validate_crc=True)
            self._chunk_records(chunk_stream.read(size), offset)
        elif opcode == Opcode.FOOTER:
            Footer.read(stream)
        # Indexes, statistics, metadata and attachments are not needed to recover messages.

    def _schema(self, schema: Schema) -> None:
        self.schemas[schema.id] = schema

    def _channel(self, channel: Channel) -> None:
        self.topics[channel.id] = channel.topic
        wanted = self.keep is None or self.keep(channel.topic)
        self.kept[channel.id] = wanted and channel.message_encoding == MESSAGE_ENCODING
        schema = self.schemas.get(channel.schema_id)
        if schema is None:
            return
        self.schema_names[channel.topic] = schema.name
        if schema.encoding == "jsonschema":
            with contextlib.suppress(ValueError):
                self.schema_docs[channel.topic] = json.loads(schema.data)

    def _chunk_records(self, data: bytes, offset: int) -> None:
        """The schemas, channels and messages inside one (decompressed, CRC-checked) chunk, in order."""
        pos = 0
        while pos < len(data):
            opcode, length = _RECORD_PREFIX.unpack_from(data, pos)
            start = pos + _RECORD_PREFIX.size
            pos = start + length
            if pos > len(data):
                raise ValueError("a record runs past the end of its chunk")
            if opcode == Opcode.MESSAGE:
                self._message(data, start, pos, offset)
            elif opcode == Opcode.SCHEMA:
                self._schema(Schema.read(ReadDataStream(io.BytesIO(data[start:pos]))))
            elif opcode == Opcode.CHANNEL:
                self._channel(Channel.read(ReadDataStream(io.BytesIO(data[start:pos]))))

    def _message(self, data: bytes, start: int, end: int, offset: int) -> None:
        """One message record's fields from ``data[start:end]``; the payload is decoded only when kept."""
        channel_id, _sequence, t, _publish_time = _MESSAGE_PREFIX.unpack_from(data, start)
        topic = self.topics.get(channel_id)
        if topic is None:
            raise RecordingError(f"{self.path}: message at byte {offset} names unknown channel {channel_id}")
        self.counts[topic] = self.counts.get(topic, 0) + 1
        self.start_ns = t if self.start_ns is None else min(self.start_ns, t)
        self.end_ns = t if self.end_ns is None else max(self.end_ns, t)
        if not self.kept[channel_id]:
            return
        raw = bytes(data[start + _MESSAGE_PREFIX.size : end])
        try:
            # Read compactly, only checked (nothing built: the bytes are decoded where they are used).
            payload: object = is_json_object(raw) if self.compact else json_object(raw)
        except ValueError as e:
            raise RecordingError(f"{self.path}: message on {topic} at byte {offset} is not JSON ({e})") from e
        if payload is False or not (self.compact or isinstance(payload, dict)):
            raise RecordingError(f"{self.path}: message on {topic} at byte {offset} is not a JSON object")
        if self.compact:
            self.messages.append(RecordedMessage(topic, t, raw=raw))
        else:
            assert isinstance(payload, dict)
            self.messages.append(RecordedMessage(topic, t, payload))

    def _done(self, cut_at: int | None, reason: str) -> RecordingRead:
        return RecordingRead(
            path=self.path,
            messages=tuple(self.messages),
            topic_counts=dict(self.counts),
            start_ns=self.start_ns,
            end_ns=self.end_ns,
            size_bytes=len(self.data),
            truncated=cut_at is not None,
            cut_at_byte=cut_at,
            cut_after_ns=self.end_ns if cut_at is not None else None,
            cut_reason=reason,
            library=self.library,
            schemas=dict(self.schema_docs),
            schema_names=dict(self.schema_names),
        )


def _opcode_name(opcode: int) -> str:
    try:
        return Opcode(opcode).name.lower()
    except ValueError:
        return f"opcode {opcode:#04x}"
