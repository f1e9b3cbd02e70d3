"""Session recording: every published message, the driver-boundary inputs and a session header, to MCAP.

A session is one MCAP file with one JSON channel per topic (the topic is the Zenoh key expression). Each
channel carries a JSON Schema derived from its first message, so generic MCAP tools can lay the fields out.

Writing happens on a background thread fed by a bounded queue: ``Recorder.write`` only serialises the
payload and appends it, so the daemon's event loop never waits for the disk; the thread wakes every
``drain_interval_s`` and writes the batch (one wake-up per batch keeps GIL hand-offs with the loop rare).
When the queue is full the message is dropped and counted (``Recorder.stats().dropped``) rather than
stalling the robot. Chunks are
small and the file is flushed after every chunk and at least every ``flush_interval_s`` of wall-clock time
(the disk's time, whatever clock the session runs on), so a crash or a ``kill -9`` loses only the last
fraction of a second.

Log times are the caller's: the session's clock (``Clock.now``, simulated time in simulation). The session
header says which clock that was and when, on the wall clock, it started.

Reading is tolerant: ``read_messages`` walks the file record by record and stops cleanly where a file whose
writer never finished ends (or turns corrupt), reporting the byte and the time of the cut. Finished files
are read the same way, so there is one code path for both.
"""

from __future__ import annotations

import collections
import contextlib
import io
import json
import mmap
import os
import struct
import threading
import time
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType
from typing import IO, Final

import structlog
from mcap.data_stream import ReadDataStream
from mcap.opcode import Opcode
from mcap.records import Channel, Chunk, Footer, Header, Schema
from mcap.stream_reader import get_chunk_data_stream
from mcap.writer import CompressionType, Writer

from daemon.errors import RecordingError

log = structlog.get_logger(__name__)

HEADER_TOPIC: Final = "session/header"
PROFILE: Final = "dishbot"
MESSAGE_ENCODING: Final = "json"
SCHEMA_ENCODING: Final = "jsonschema"
MCAP_MAGIC: Final = b"\x89MCAP0\r\n"
COMPRESSIONS: Final = {None: CompressionType.NONE, "zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4}

_RECORD_PREFIX = struct.Struct("<BQ")  # opcode, record length
_MESSAGE_PREFIX = struct.Struct("<HIQQ")  # channel id, sequence, log time, publish time; then the data


@dataclass(frozen=True, slots=True)
class RecorderStats:
    """What a recorder has done so far; after ``close`` every accepted message is written or dropped."""

    written: int  # messages in the file (handed to the OS)
    dropped: int  # messages lost (queue full) or not confirmed in the file (the disk failed)
    bytes_written: int  # size of the file
    queued: int  # accepted, not yet in the file (in the queue or the open chunk)


@dataclass(frozen=True, slots=True)
class _Item:
    topic: str
    log_time_ns: int
    data: bytes
    flush_now: bool = False


class Recorder:
    """Writes one session to an MCAP file; a context manager that finishes the file on exit.

    ``write`` and ``write_header`` are thread-safe and never block: call them from the event loop (or a
    Zenoh callback). ``close`` blocks until the queue is drained and the summary is written; from the event
    loop call it through ``asyncio.to_thread``. If the disk fails, the failure is logged once, kept in
    ``failure``, and every later message counts as dropped; the file stays readable up to the failure.
    """

    def __init__(
        self,
        path: Path,
        *,
        chunk_size: int = 65536,
        compression: str | None = None,
        flush_interval_s: float = 0.5,
        queue_size: int = 8192,
        drain_interval_s: float = 0.05,
    ) -> None:
        if compression not in COMPRESSIONS:
            raise RecordingError(
                f"recording compression {compression!r} is not supported; use one of: none, zstd, lz4"
            )
        if chunk_size < 1024:
            raise RecordingError(f"recording chunk_size {chunk_size} is too small; use at least 1024 bytes")
        if not 0.0 < flush_interval_s <= 10.0:
            raise RecordingError(f"recording flush_interval_s {flush_interval_s} is out of range (0, 10] s")
        if not 0.0 < drain_interval_s <= flush_interval_s:
            raise RecordingError(
                f"recording drain_interval_s {drain_interval_s} is out of range (0, flush_interval_s]"
            )
        if queue_size < 1:
            raise RecordingError(f"recording queue_size {queue_size} must be at least 1")
        self.path = Path(path)
        try:
            self._file: IO[bytes] = open(self.path, "xb")  # noqa: SIM115 — owned until close()
        except FileExistsError as e:
            raise RecordingError(f"recording {self.path} already exists; choose a new file name") from e
        except OSError as e:
            raise RecordingError(f"cannot create recording {self.path}: {e.strerror}") from e
        self._writer = Writer(self._file, chunk_size=chunk_size, compression=COMPRESSIONS[compression])
        try:
            self._writer.start(profile=PROFILE, library="dishbot")
            self._file.flush()
        except OSError as e:
            self._file.close()
            raise RecordingError(f"cannot write recording {self.path}: {e.strerror}") from e
        self._flush_interval_s = flush_interval_s
        self._drain_interval_s = drain_interval_s
        self._queue_size = queue_size
        self._pending: collections.deque[_Item] = collections.deque()
        self._wake = threading.Event()
        self._lock = threading.Lock()
        self._closed = False
        self._header_written = False
        self._written = 0
        self._unflushed = 0  # messages given to the MCAP writer but not yet to the OS (writer thread only)
        self._dropped = 0
        self.failure: BaseException | None = None
        self._sequence: dict[int, int] = {}
        self._thread = threading.Thread(target=self._run, name=f"recorder:{self.path.name}", daemon=True)
        self._thread.start()
        log.info("recording_started", path=str(self.path), chunk_size=chunk_size, compression=compression)

    def __enter__(self) -> Recorder:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()

    def write(self, topic: str, payload: Mapping[str, object], *, log_time_ns: int) -> bool:
        """Queue one message; False (counted as dropped) when the queue is full or the disk has failed.

        Raises ``RecordingError`` for a closed recorder, an empty topic, a negative time or a payload that
        is not a JSON object (NaN and infinities included: they are not JSON).
        """
        return self._enqueue(topic, payload, log_time_ns=log_time_ns, flush_now=False)

    def write_header(
        self,
        config: Mapping[str, object],
        scene: Mapping[str, object],
        *,
        log_time_ns: int,
        clock: Mapping[str, object] | None = None,
    ) -> bool:
        """Record the session header: the effective config, the initial scene and the session's clock
        (``SessionClock.describe()``: its source and its wall-clock start), flushed at once.

        ``log_time_ns`` is on the clock the other messages use (the session's start)."""
        with self._lock:
            if self._header_written:
                raise RecordingError(f"recording {self.path} already has a session header")
            self._header_written = True
        payload: dict[str, object] = {"config": dict(config), "scene": dict(scene)}
        if clock is not None:
            payload["clock"] = dict(clock)
        return self._enqueue(HEADER_TOPIC, payload, log_time_ns=log_time_ns, flush_now=True)

    def stats(self) -> RecorderStats:
        with self._lock:
            return RecorderStats(
                written=self._written,
                dropped=self._dropped,
                bytes_written=self._bytes_on_disk(),
                queued=len(self._pending) + self._unflushed,
            )

    def close(self) -> RecorderStats:
        """Drain the queue, finish the file (summary, footer) and close it. Idempotent."""
        with self._lock:
            already = self._closed
            self._closed = True
        self._wake.set()
        self._thread.join()
        stats = self.stats()
        if not already:
            log.info(
                "recording_closed",
                path=str(self.path),
                written=stats.written,
                dropped=stats.dropped,
                bytes=stats.bytes_written,
                failed=self.failure is not None,
            )
        return stats

    def _enqueue(
        self, topic: str, payload: Mapping[str, object], *, log_time_ns: int, flush_now: bool
    ) -> bool:
        if not topic:
            raise RecordingError("recording topic must be a non-empty key expression")
        if not isinstance(payload, Mapping):
            raise RecordingError(
                f"recording payload for {topic!r} must be a JSON object, got {type(payload).__name__}"
            )
        if isinstance(log_time_ns, bool) or not isinstance(log_time_ns, int) or not 0 <= log_time_ns < 2**64:
            raise RecordingError(f"recording log_time_ns for {topic!r} must be an integer in [0, 2**64)")
        try:
            data = json.dumps(payload, separators=(",", ":"), allow_nan=False).encode()
        except (TypeError, ValueError) as e:
            raise RecordingError(f"recording payload for {topic!r} is not JSON: {e}") from e
        with self._lock:
            if self._closed:
                raise RecordingError(f"recording {self.path} is closed; open a new Recorder")
            if self.failure is not None:
                self._dropped += 1
                return False
            if len(self._pending) >= self._queue_size:
                self._dropped += 1
                if self._dropped == 1 or self._dropped % 1000 == 0:
                    log.warning("recording_queue_full", path=str(self.path), dropped=self._dropped)
                return False
            self._pending.append(_Item(topic, log_time_ns, data, flush_now))
        if flush_now:
            self._wake.set()
        return True

    def _bytes_on_disk(self) -> int:
        try:
            return self.path.stat().st_size
        except OSError:
            return 0

    def _run(self) -> None:
        """Write pending messages in batches, one wake-up per ``drain_interval_s`` rather than per message."""
        channel_ids: dict[str, int] = {}
        last_flush = time.monotonic()
        dirty = False
        while True:
            self._wake.wait(timeout=self._drain_interval_s)
            self._wake.clear()
            with self._lock:
                closing = self._closed  # nothing is appended after this turns True
            flush_now = False
            while self._pending:
                item = self._pending.popleft()
                if self._write_or_drop(item, channel_ids):
                    dirty = True
                    flush_now = flush_now or item.flush_now
            due = flush_now or time.monotonic() - last_flush >= self._flush_interval_s
            if dirty and due and self.failure is None:
                try:
                    self._writer.flush()  # type: ignore[no-untyped-call]  # mcap leaves it unannotated
                    self._settle()
                except Exception as e:  # the disk failed: keep the robot running, say so once
                    self._fail(e)
                dirty = False
                last_flush = time.monotonic()
            if closing:
                break
        self._finish()

    def _write_or_drop(self, item: _Item, channel_ids: dict[str, int]) -> bool:
        """Write one message; after a disk failure count it as dropped instead. True when written."""
        if self.failure is not None:
            with self._lock:
                self._dropped += 1
            return False
        try:
            self._write_item(item, channel_ids)
        except Exception as e:  # the disk or the encoder failed: keep the robot running, say so once
            self._fail(e)
            return False
        return True

    def _write_item(self, item: _Item, channel_ids: dict[str, int]) -> None:
        """Add one message, registering its channel first; flush the file when a chunk was just emitted."""
        channel_id = channel_ids.get(item.topic)
        if channel_id is None:
            sample = json.loads(item.data)
            schema = json.dumps(_schema_document(item.topic, sample), separators=(",", ":")).encode()
            schema_id = self._writer.register_schema(name=item.topic, encoding=SCHEMA_ENCODING, data=schema)
            channel_id = self._writer.register_channel(
                topic=item.topic, message_encoding=MESSAGE_ENCODING, schema_id=schema_id
            )
            channel_ids[item.topic] = channel_id
        sequence = self._sequence.get(channel_id, 0)
        self._sequence[channel_id] = sequence + 1
        before = self._file.tell()
        self._unflushed += 1
        self._writer.add_message(
            channel_id=channel_id,
            log_time=item.log_time_ns,
            data=item.data,
            publish_time=item.log_time_ns,
            sequence=sequence,
        )
        if self._file.tell() != before:  # a chunk was finished and handed to the file
            self._file.flush()
            self._settle()

    def _settle(self) -> None:
        """Everything given to the MCAP writer so far is now in the file: count it as written."""
        with self._lock:
            self._written += self._unflushed
            self._unflushed = 0

    def _fail(self, error: BaseException) -> None:
        """Stop writing after a disk or encoder error; messages not yet in the file count as dropped."""
        with self._lock:
            self.failure = error
            self._dropped += self._unflushed
            self._unflushed = 0
        log.error("recording_failed", path=str(self.path), error=str(error))
        with contextlib.suppress(OSError, ValueError):
            self._file.flush()

    def _finish(self) -> None:
        try:
            if self.failure is None:
                self._writer.finish()  # type: ignore[no-untyped-call]  # mcap leaves it unannotated
                self._settle()
        except Exception as e:  # a failing disk at the very end still leaves a readable, truncated file
            self._fail(e)
        finally:
            with contextlib.suppress(OSError):
                self._file.close()


def _schema_document(topic: str, sample: Mapping[str, object]) -> dict[str, object]:
    doc: dict[str, object] = {"$schema": "https://json-schema.org/draft/2020-12/schema", "title": topic}
    doc.update(json_schema_of(sample))
    return doc


def json_schema_of(value: object) -> dict[str, object]:
    """A loose JSON Schema describing ``value``'s shape: types and field names, nothing required.

    Integers are described as numbers and nulls as "anything", because the first message of a topic often
    carries ``0`` or ``None`` where later ones carry a float.
    """
    if isinstance(value, bool):
        return {"type": "boolean"}
    if isinstance(value, int | float):
        return {"type": "number"}
    if isinstance(value, str):
        return {"type": "string"}
    if isinstance(value, Mapping):
        return {"type": "object", "properties": {str(k): json_schema_of(v) for k, v in value.items()}}
    if isinstance(value, list | tuple):
        return {"type": "array", "items": json_schema_of(value[0])} if value else {"type": "array"}
    return {}


# --- reading ---------------------------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class RecordedMessage:
    """One message as recorded: its topic (key expression), log time and decoded JSON payload."""

    topic: str
    log_time_ns: int
    payload: dict[str, object]


@dataclass(frozen=True, slots=True)
class RecordingRead:
    """Everything recovered from a recording, in file order, and whether (and where) the file was cut.

    ``truncated`` is True when the file does not end with a footer and the closing magic (the writer was
    killed, the disk filled, the file was copied partway) or a record turned out corrupt. ``cut_at_byte``
    is the offset of the first byte that could not be used; ``cut_after_ns`` the log time of the last
    message recovered before it (None when nothing was). ``cut_reason`` says why reading stopped.
    ``topic_counts``, ``start_ns`` and ``end_ns`` cover every recovered message, also those not kept.
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

    def __iter__(self) -> Iterator[RecordedMessage]:
        return iter(self.messages)

    def __len__(self) -> int:
        return len(self.messages)

    @property
    def message_count(self) -> int:
        return sum(self.topic_counts.values())

    @property
    def header(self) -> dict[str, object] | None:
        """The session header payload (``config`` and ``scene``), or None when none was kept or recorded."""
        return next((m.payload for m in self.messages if m.topic == HEADER_TOPIC), None)


def read_messages(path: Path, *, keep: Callable[[str], bool] | None = None) -> RecordingRead:
    """Read a recording, finished or not, up to the first byte that cannot be used.

    ``keep(topic)`` selects the topics whose payloads are decoded and returned (default: all); the others
    are only counted, which keeps summaries of long sessions cheap. Raises ``RecordingError`` (one line,
    naming the file) when the file is missing, empty or not MCAP, or a message in an intact chunk is not a
    JSON object.
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
                return _Scan(path, data, keep).run()
    except FileNotFoundError as e:
        raise RecordingError(f"{path}: no such file") from e
    except IsADirectoryError as e:
        raise RecordingError(f"{path}: is a directory, not a recording file") from e
    except PermissionError as e:
        raise RecordingError(f"{path}: permission denied") from e


class _Scan:
    """One pass over the records of a mapped file, tolerant of a missing end."""

    def __init__(self, path: Path, data: mmap.mmap, keep: Callable[[str], bool] | None) -> None:
        self.path = path
        self.data = data
        self.keep = keep
        self.topics: dict[int, str] = {}
        self.kept: dict[int, bool] = {}
        self.schemas: dict[int, bytes] = {}
        self.schema_docs: dict[str, object] = {}
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
        self.schemas[schema.id] = schema.data

    def _channel(self, channel: Channel) -> None:
        self.topics[channel.id] = channel.topic
        wanted = self.keep is None or self.keep(channel.topic)
        self.kept[channel.id] = wanted and channel.message_encoding == MESSAGE_ENCODING
        schema = self.schemas.get(channel.schema_id, b"")
        if schema:
            with contextlib.suppress(ValueError):
                self.schema_docs[channel.topic] = json.loads(schema)

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
        try:
            payload = json.loads(data[start + _MESSAGE_PREFIX.size : end])
        except ValueError as e:
            raise RecordingError(f"{self.path}: message on {topic} at byte {offset} is not JSON ({e})") from e
        if not isinstance(payload, dict):
            raise RecordingError(f"{self.path}: message on {topic} at byte {offset} is not a JSON object")
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
        )


def _opcode_name(opcode: int) -> str:
    try:
        return Opcode(opcode).name.lower()
    except ValueError:
        return f"opcode {opcode:#04x}"
