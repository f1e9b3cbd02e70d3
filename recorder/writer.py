"""Writing sessions to MCAP: every published message, the driver-boundary inputs and a header, per file.

Each topic (a Zenoh key expression) is one JSON channel whose JSON Schema comes from
``wire.schemas``. A ``Deriver`` may turn recorded messages into further messages written beside
them in the same file (the Foxglove channels: protobuf with Foxglove's well-known schemas), and a ``Tee``
receives everything written (the live Foxglove server).

Writing happens on a background thread fed by a bounded queue: ``Recorder.write`` only serialises the
payload and appends it, so the daemon's event loop never waits for the disk, for the derived messages or for
the live server; the thread wakes every ``drain_interval_s`` and handles the batch. When the queue is full
the message is dropped and counted (``Recorder.stats().dropped``) rather than stalling the robot; a
``lossless`` recorder (simulated time) keeps it instead, and its clock waits (``caught_up``) before moving
on while the queue is behind. Chunks are
small and the file is flushed after every chunk and at least every ``flush_interval_s``, so a crash or a
``kill -9`` loses only the last fraction of a second. While a file is open its writer holds an exclusive
``flock`` on it: a reader can tell a file being written from one cut by a crash (``reader.being_written``).

A disk that fails (full, gone) costs only what could not be written: the recorder goes on as soon as
there is room again, in the same file when the failure left it intact (a disk that refused the message
before any of it was written), otherwise in a new file of the same stream (``-1`` added to its name, its
header marked ``file.continues``), tried again every ``retry_s`` of log time.

``rotate`` finishes the current file and goes on in a new one at that point of the stream: the daemon starts
a file per job and rotates idle files. Every file starts with its header and the deriver's ``opening``
messages (the scene as it stands), so every file can be read on its own. A file may thin the high-rate
telemetry to ``thin_hz`` (idle files); the tee still gets every message.
"""

from __future__ import annotations

import collections
import contextlib
import errno
import fcntl
import functools
import io
import json
import os
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import IO, TYPE_CHECKING, Final, Protocol

import structlog
from mcap.writer import CompressionType, Writer

from recorder.errors import RecordingError
from wire.messages import Message, Payload, decode, encode, message_type, topic_suffix
from wire.schemas import HEADER_TOPIC, is_telemetry, schema_bytes, schema_name

if TYPE_CHECKING:
    from _typeshed import ReadableBuffer

log = structlog.get_logger(__name__)

PROFILE: Final = "dishbot"
MESSAGE_ENCODING: Final = "json"
SCHEMA_ENCODING: Final = "jsonschema"
COMPRESSIONS: Final = {None: CompressionType.NONE, "zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4}
_MAX_NAME_TRIES = 100
# A lossless recorder's queue counts as caught up at or below this share of ``queue_size``.
_CAUGHT_UP_SHARE = 0.25


@dataclass(frozen=True, slots=True)
class ChannelSpec:
    """A channel as written to the file and offered to the live server: topic, encodings and schema."""

    topic: str
    message_encoding: str
    schema_name: str
    schema_encoding: str
    schema_data: bytes


@functools.lru_cache(maxsize=256)
def json_channel(topic: str) -> ChannelSpec:
    """The JSON channel of a recorded topic, with its schema from ``wire.schemas``."""
    return ChannelSpec(topic, MESSAGE_ENCODING, schema_name(topic), SCHEMA_ENCODING, schema_bytes(topic))


@dataclass(frozen=True, slots=True)
class Derived:
    """A message derived from a recorded one (or from the state a new file opens with)."""

    channel: ChannelSpec
    data: bytes
    log_time_ns: int


class Deriver(Protocol):
    """Turns recorded messages into further messages (``recorder.foxglove_scene.SceneView`` is one).

    Called on the recorder's thread only, in stream order."""

    def wants(self, topic: str) -> bool: ...

    def derive(
        self, topic: str, payload: Mapping[str, object] | Message, log_time_ns: int
    ) -> Sequence[Derived]: ...

    def opening(self, log_time_ns: int) -> Sequence[Derived]: ...


# Told of the recording's health: (file, error) when writing a file failed, (file, None) once writing again.
HealthListener = Callable[[Path, str | None], None]


class Tee(Protocol):
    """Receives every message the recorder handles, thinned or not (``recorder.foxglove_server``)."""

    def send(self, channel: ChannelSpec, data: bytes, log_time_ns: int) -> None: ...


@dataclass(frozen=True, slots=True)
class RecorderStats:
    """What a recorder has done so far; after ``close`` every accepted message is written or dropped."""

    written: int  # messages in the files (handed to the OS)
    dropped: int  # messages lost (queue full) or not confirmed in the file (the disk failed)
    bytes_written: int  # size of the files written so far
    queued: int  # accepted, not yet in the file (in the queue or the open chunk)
    thinned: int = 0  # telemetry left out of idle files on purpose (not lost: the rate was lowered)
    files: int = 1  # files opened, the current one included


@dataclass(frozen=True, slots=True)
class _Item:
    topic: str
    log_time_ns: int
    data: bytes
    flush_now: bool = False


@dataclass(frozen=True, slots=True)
class _Rotate:
    path: Path
    header: Mapping[str, object]
    log_time_ns: int
    thin_hz: float | None
    on_open: Callable[[Path], None] | None


class DiskSpace:
    """Whether the disk under the recording has room, by log time: between ``fill(t)`` and ``free(t)`` every
    message fails to reach the file with ENOSPC, as on a full disk (the ``disk_full`` fault of a fault
    file), and the recorder takes its own disk-failure path. Kept by log time rather than by the moment the
    writer thread gets to a message, so that on a simulated clock the same messages fail every run.
    Thread-safe."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._full: list[tuple[int, int | None]] = []  # [from, until) in log-time nanoseconds

    def fill(self, log_time_ns: int) -> None:
        with self._lock:
            if not self._full or self._full[-1][1] is not None:
                self._full.append((log_time_ns, None))

    def free(self, log_time_ns: int) -> None:
        with self._lock:
            if self._full and self._full[-1][1] is None:
                self._full[-1] = (self._full[-1][0], log_time_ns)

    def filling(self) -> bool:
        """Whether the disk has been filled and not freed yet. Read without the lock (the recorder asks
        before every step of simulated time): the list only grows, and its last entry is replaced whole."""
        full = self._full
        return bool(full) and full[-1][1] is None

    def full_at(self, log_time_ns: int) -> bool:
        with self._lock:
            return any(a <= log_time_ns and (b is None or log_time_ns < b) for a, b in self._full)

    def check(self, path: Path, log_time_ns: int) -> None:
        """Raise ENOSPC for a message logged while the disk is full (before any of it reaches the file)."""
        if self.full_at(log_time_ns):
            raise _Refused(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))


class _Refused(OSError):
    """The disk refused a message before any byte of it reached the file: the file can be continued."""


class _Counted(io.BufferedWriter):
    """A new file written from its start, which counts the bytes written instead of asking the OS where it
    is: ``tell`` is asked twice per message (whether the message finished a chunk) and by the MCAP writer
    per chunk, and the OS's answer is a system call that also hands the GIL to the daemon's loop and back."""

    def __init__(self, raw: io.RawIOBase) -> None:
        super().__init__(raw)
        self._position = 0

    def write(self, buffer: ReadableBuffer, /) -> int:
        written = super().write(buffer)
        self._position += written
        return written

    def tell(self) -> int:
        return self._position


class _File:
    """One open MCAP file: its writer, channel ids and sequence numbers, and the writer's lock on it.

    ``log_time_ns`` is when it is opened: on a disk that is full then, there is no room for a new file."""

    def __init__(
        self,
        path: Path,
        *,
        chunk_size: int,
        compression: CompressionType,
        disk: DiskSpace | None = None,
        log_time_ns: int | None = None,
    ) -> None:
        self.path = path
        self.disk = disk or DiskSpace()
        if log_time_ns is not None and self.disk.full_at(log_time_ns):
            raise RecordingError(f"cannot create recording {path}: {os.strerror(errno.ENOSPC)}")
        try:
            self.file: IO[bytes] = _Counted(open(path, "xb").detach())  # noqa: SIM115 — owned until close()
        except FileExistsError as e:
            raise RecordingError(f"recording {path} already exists; choose a new file name") from e
        except OSError as e:
            raise RecordingError(f"cannot create recording {path}: {e.strerror}") from e
        try:
            # Held until the file is closed: `record info` tells a file being written from a crashed one.
            fcntl.flock(self.file.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
            self.writer = Writer(self.file, chunk_size=chunk_size, compression=compression)
            self.writer.start(profile=PROFILE, library="dishbot")
            self.file.flush()
        except OSError as e:
            with contextlib.suppress(OSError):
                self.file.close()
            with contextlib.suppress(OSError):
                path.unlink()  # nothing of it is readable: leave no empty file behind
            raise RecordingError(f"cannot write recording {path}: {e.strerror}") from e
        self.channels: dict[str, int] = {}
        self.sequence: dict[int, int] = {}
        self.header_written = False

    def add(self, channel: ChannelSpec, data: bytes, log_time_ns: int) -> bool:
        """Add one message, registering its channel first; True when a chunk was handed to the file."""
        channel_id = self.channels.get(channel.topic)
        if channel_id is None:
            schema_id = self.writer.register_schema(
                name=channel.schema_name, encoding=channel.schema_encoding, data=channel.schema_data
            )
            channel_id = self.writer.register_channel(
                topic=channel.topic, message_encoding=channel.message_encoding, schema_id=schema_id
            )
            self.channels[channel.topic] = channel_id
        self.disk.check(self.path, log_time_ns)
        sequence = self.sequence.get(channel_id, 0)
        self.sequence[channel_id] = sequence + 1
        before = self.file.tell()
        self.writer.add_message(
            channel_id=channel_id,
            log_time=log_time_ns,
            data=data,
            publish_time=log_time_ns,
            sequence=sequence,
        )
        return self.file.tell() != before

    def size(self) -> int:
        try:
            return self.path.stat().st_size
        except OSError:
            return 0


class Recorder:
    """Writes a session to MCAP files, one at a time; a context manager that finishes the file on exit.

    ``write``, ``write_header`` and ``rotate`` are thread-safe and never block: call them from the event
    loop (or a Zenoh callback). ``close`` blocks until the queue is drained and the summary is written; from
    the event loop call it through ``asyncio.to_thread``. If the disk fails, the failure is logged once and
    kept in ``failure``, and every message until there is room again counts as dropped; the failed file
    stays readable up to the failure. Writing goes on as soon as there is room: in the same file when it is
    intact, else in a new file (tried every ``retry_s`` of log time), or in the next ``rotate``'s.
    ``on_health(path, error)`` hears of it on the recorder's thread (it must not block): once with the
    error when writing fails, once with None (and the file written now) when it works again.

    ``lossless`` (for simulated time) never drops a message for a full queue: the queue grows instead, and
    the clock holds time back while ``caught_up`` says the writer is behind.
    """

    def __init__(
        self,
        path: Path,
        *,
        chunk_size: int = 65536,
        compression: str | None = "zstd",
        flush_interval_s: float = 0.5,
        queue_size: int = 8192,
        drain_interval_s: float = 0.05,
        thin_hz: float | None = None,
        deriver: Deriver | None = None,
        tee: Tee | None = None,
        disk: DiskSpace | None = None,
        on_health: HealthListener | None = None,
        lossless: bool = False,
        retry_s: float = 1.0,
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
        if not 0.0 < retry_s <= 3600.0:
            raise RecordingError(f"recording retry_s {retry_s} is out of range (0, 3600] s")
        _check_thin(thin_hz)
        self._chunk_size = chunk_size
        self._compression = COMPRESSIONS[compression]
        self.disk = disk or DiskSpace()
        self._file: _File | None = _File(
            Path(path), chunk_size=chunk_size, compression=self._compression, disk=self.disk
        )
        self._path = Path(path)
        self._stream = self._path  # the name asked for the current stream; a continuation is numbered from it
        self._paths = [self._path]
        self._flush_interval_s = flush_interval_s
        self._drain_interval_s = drain_interval_s
        self._queue_size = queue_size
        self._lossless = lossless
        self._caught_up_at = max(1, int(queue_size * _CAUGHT_UP_SHARE))
        self._retry_ns = round(retry_s * 1e9)
        self._retry_at_ns: int | None = None  # when to try a new file next, after a failure (thread only)
        self._broken = False  # the failed file cannot be continued (thread only)
        self._header: bytes | None = None  # the current file's header, for a file continuing it
        self._unopened: tuple[Path, dict[str, object]] | None = None  # a rotation's file not opened yet
        self._drained = threading.Condition()
        self._busy = False  # the writer is handling a batch (thread only writes it)
        self._deriver = deriver
        self._tee = tee
        self._on_health = on_health
        self._pending: collections.deque[_Item | _Rotate] = collections.deque()
        self._wake = threading.Event()
        self._lock = threading.Lock()
        self._closed = False
        self._header_pending = True  # the current file may still get its header (caller side)
        self._written = 0
        self._unflushed = 0  # messages given to the MCAP writer but not yet to the OS (writer thread only)
        self._dropped = 0
        self._thinned = 0
        self._bytes_done = 0  # sizes of the files already finished
        self._thin_hz = thin_hz
        self._last_kept: dict[str, int] = {}
        self._warned: set[str] = set()
        self.failure: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name=f"recorder:{self._path.name}", daemon=True)
        self._thread.start()
        log.info("recording_started", path=str(self._path), chunk_size=chunk_size, compression=compression)

    def __enter__(self) -> Recorder:
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()

    @property
    def path(self) -> Path:
        """The file being written now (the last one once closed)."""
        with self._lock:
            return self._path

    @property
    def paths(self) -> tuple[Path, ...]:
        """Every file this recorder opened, in order."""
        with self._lock:
            return tuple(self._paths)

    def write(self, topic: str, payload: Payload, *, log_time_ns: int, data: bytes | None = None) -> bool:
        """Queue one message (its declared struct, or a JSON object); False (counted as dropped) when the
        queue is full or the disk has failed.
        ``data``: the payload's bytes as ``wire.messages.encode`` wrote them (for Zenoh), recorded as they
        are instead of encoding the payload again.

        Raises ``RecordingError`` for a closed recorder, an empty topic, a negative time or a payload that
        is not a JSON object (NaN and infinities included: they are not JSON).
        """
        return self._enqueue(topic, payload, log_time_ns=log_time_ns, flush_now=False, data=data)

    def write_header(
        self,
        config: Mapping[str, object],
        scene: Mapping[str, object],
        *,
        log_time_ns: int,
        job: Mapping[str, object] | None = None,
        file: Mapping[str, object] | None = None,
        clock: Mapping[str, object] | None = None,
    ) -> bool:
        """Record the current file's header (the effective config, the scene, for a job file what the job
        runs, and the session's clock: ``SessionClock.describe()``, its source and wall-clock start),
        flushed at once. ``log_time_ns`` is on the clock the other messages use. A file opened by ``rotate``
        has its header already."""
        with self._lock:
            if not self._header_pending:
                raise RecordingError(f"recording {self._path} already has a session header")
            self._header_pending = False
        payload = header_payload(config, scene, job=job, file=file, clock=clock)
        return self._enqueue(HEADER_TOPIC, payload, log_time_ns=log_time_ns, flush_now=True)

    def rotate(
        self,
        path: Path,
        header: Mapping[str, object],
        *,
        log_time_ns: int,
        thin_hz: float | None = None,
        on_open: Callable[[Path], None] | None = None,
    ) -> None:
        """Finish the current file after the messages queued so far and go on in a new file at ``path``
        (a ``-N`` suffix is added when it exists), starting with ``header`` (``header_payload``; its
        ``file.previous``, when there, is set to the name of the file just finished) and the deriver's
        opening messages. ``on_open(path)`` then runs on the recorder's thread (retention). The rotation is
        never dropped, even when the queue is full."""
        _check_thin(thin_hz)
        _check_time(HEADER_TOPIC, log_time_ns)
        _encode(HEADER_TOPIC, header)  # refuse a header that is not JSON here, not on the thread
        with self._lock:
            if self._closed:
                raise RecordingError(f"recording {self._path} is closed; open a new Recorder")
            self._header_pending = False
            self._pending.append(_Rotate(Path(path), dict(header), log_time_ns, thin_hz, on_open))
        self._wake.set()

    def caught_up(self, wait_s: float = 0.0) -> bool:
        """Whether the writer has caught up (its queue at or below a quarter of ``queue_size``; empty while
        the disk is full or has failed, so that the failure and the recovery are seen, and published, at the
        clock's time of the message they happened at), waiting up to ``wait_s`` seconds for it; a closed
        recorder has. For a clock holding time back (``lossless``): it asks before every step of time, so
        the common answer (not behind) takes no lock."""
        if not self._behind():
            return True
        with self._drained:
            if self._behind():
                self._wake.set()  # no nap between batches while someone waits
                self._drained.wait_for(lambda: not self._behind(), timeout=wait_s)
            return not self._behind()

    def _behind(self) -> bool:
        """Lock-free reads (the queue's length, the failure, the disk's state); whether the writer thread
        still runs, which takes a lock, is asked last and only of a queue that is behind."""
        if self.failure is not None or self.disk.filling():
            behind = bool(self._pending) or self._busy
        else:
            behind = len(self._pending) > self._caught_up_at
        return behind and self._thread.is_alive()

    @property
    def dropped(self) -> int:
        """Messages lost so far (``stats().dropped``, without looking at the file)."""
        with self._lock:
            return self._dropped

    def stats(self) -> RecorderStats:
        with self._lock:
            current = self._file.size() if self._file is not None else 0
            return RecorderStats(
                written=self._written,
                dropped=self._dropped,
                bytes_written=self._bytes_done + current,
                queued=sum(isinstance(p, _Item) for p in self._pending) + self._unflushed,
                thinned=self._thinned,
                files=len(self._paths),
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
                files=stats.files,
                written=stats.written,
                dropped=stats.dropped,
                thinned=stats.thinned,
                bytes=stats.bytes_written,
                failed=self.failure is not None,
            )
        return stats

    def _enqueue(
        self,
        topic: str,
        payload: Payload,
        *,
        log_time_ns: int,
        flush_now: bool,
        data: bytes | None = None,
    ) -> bool:
        if data is None or not topic:
            data = _encode(topic, payload)
        _check_time(topic, log_time_ns)
        with self._lock:
            if self._closed:
                raise RecordingError(f"recording {self._path} is closed; open a new Recorder")
            # Lossless: the queue grows, and the clock waits for the writer (unless the writer is gone).
            full = len(self._pending) >= self._queue_size and not (self._lossless and self._thread.is_alive())
            if full:
                self._dropped += 1
                dropped = self._dropped
            else:
                self._pending.append(_Item(topic, log_time_ns, data, flush_now))
        if full:
            # Logged outside the lock: the record itself comes back here through the `log` topic.
            if dropped == 1 or dropped % 1000 == 0:
                log.warning("recording_queue_full", path=str(self.path), dropped=dropped)
            return False
        if flush_now:
            self._wake.set()
        return True

    # --- the recorder's thread ------------------------------------------------------------------------------

    def _run(self) -> None:
        """Handle pending items in batches, one wake-up per ``drain_interval_s`` rather than per message."""
        last_flush = time.monotonic()
        dirty = False
        while True:
            self._wake.wait(timeout=self._drain_interval_s)
            self._wake.clear()
            with self._lock:
                closing = self._closed  # nothing is appended after this turns True
            flush_now = False
            handled = 0
            self._busy = True
            while self._pending:  # only this thread takes items out; deque's popleft is atomic
                handled += 1
                if handled % 256 == 0:
                    self._notify_drained()
                item = self._pending.popleft()
                if isinstance(item, _Rotate):
                    self._switch(item)
                    dirty = False
                    last_flush = time.monotonic()
                    continue
                if self._handle(item):
                    dirty = True
                    flush_now = flush_now or item.flush_now
            due = flush_now or time.monotonic() - last_flush >= self._flush_interval_s
            if dirty and due:
                self._flush()
                dirty = False
                last_flush = time.monotonic()
            self._busy = False
            self._notify_drained()
            if closing:
                break
        self._finish()
        self._notify_drained()

    def _notify_drained(self) -> None:
        with self._drained:
            self._drained.notify_all()

    def _handle(self, item: _Item) -> bool:
        """Write one message and what derives from it, tee them; True when something went to the file."""
        keep = self._kept(item)
        if item.topic == HEADER_TOPIC:
            self._header = item.data
        channel = json_channel(item.topic)
        wrote = keep and self._add(channel, item.data, item.log_time_ns)
        self._send(channel, item.data, item.log_time_ns)
        derived = self._opening(item.log_time_ns) if item.topic == HEADER_TOPIC else self._derived(item)
        for d in derived:
            if keep:
                wrote = self._add(d.channel, d.data, d.log_time_ns) or wrote
            self._send(d.channel, d.data, d.log_time_ns)
        return wrote

    def _kept(self, item: _Item) -> bool:
        """Whether a message goes to the file: telemetry in a thinned file only every 1/thin_hz seconds."""
        if self._thin_hz is None or not is_telemetry(item.topic):
            return True
        last = self._last_kept.get(item.topic)
        if last is not None and item.log_time_ns - last < 1e9 / self._thin_hz:
            with self._lock:
                self._thinned += 1
            return False
        self._last_kept[item.topic] = item.log_time_ns
        return True

    def _derived(self, item: _Item) -> Sequence[Derived]:
        deriver = self._deriver
        if deriver is None or not deriver.wants(item.topic):
            return ()
        try:
            return deriver.derive(item.topic, _decoded(item.topic, item.data), item.log_time_ns)
        except Exception as e:  # a bad message or a bug there must not stop the recording
            self._warn_once(f"derive:{item.topic}", "recording_derive_failed", topic=item.topic, error=str(e))
            return ()

    def _opening(self, log_time_ns: int) -> Sequence[Derived]:
        """What a file starts with after its header: the deriver's scene as it stands."""
        if self._deriver is None:
            return ()
        try:
            return self._deriver.opening(log_time_ns)
        except Exception as e:  # a bug there must not stop the recording
            self._warn_once("opening", "recording_derive_failed", topic=HEADER_TOPIC, error=str(e))
            return ()

    def _send(self, channel: ChannelSpec, data: bytes, log_time_ns: int) -> None:
        if self._tee is None:
            return
        try:
            self._tee.send(channel, data, log_time_ns)
        except Exception as e:  # the live view failing must not stop the recording
            self._warn_once(f"tee:{channel.topic}", "recording_tee_failed", topic=channel.topic, error=str(e))

    def _warn_once(self, key: str, event: str, **detail: object) -> None:
        if key not in self._warned:
            self._warned.add(key)
            log.warning(event, **detail)

    def _add(self, channel: ChannelSpec, data: bytes, log_time_ns: int) -> bool:
        """Add one message to the current file; while the disk has failed and there is no room yet, count
        it as dropped instead."""
        if (self._file is None or self.failure is not None) and not self._recover(log_time_ns):
            with self._lock:
                self._dropped += 1
            return False
        file = self._file
        assert file is not None
        try:
            with self._lock:
                self._unflushed += 1
            if file.add(channel, data, log_time_ns):  # a chunk was finished and handed to the file
                file.file.flush()
                self._settle()
        except _Refused as e:  # nothing of it reached the file: the file is intact, only this one is lost
            with self._lock:
                self._unflushed -= 1
                self._dropped += 1
            if self.failure is None:
                self._fail(e, broken=False)
            return False
        except Exception as e:  # the disk or the encoder failed: keep the robot running, say so once
            self._fail(e)
            return False
        return True

    def _recover(self, log_time_ns: int) -> bool:
        """After a failure, whether writing can go on now: in the same file when it is intact and the disk
        has room at ``log_time_ns``, else in a new file of the same stream (tried every ``retry_s``)."""
        file = self._file
        if file is not None and not self._broken:
            if self.disk.full_at(log_time_ns):
                return False
            self._restored(file.path)
            return True
        if self._retry_at_ns is not None and log_time_ns < self._retry_at_ns:
            return False
        self._retry_at_ns = log_time_ns + self._retry_ns
        return self._continue(log_time_ns)

    def _continue(self, log_time_ns: int) -> bool:
        """Go on in a new file after the one that failed: the same header (``file.continues``, ``previous``
        naming the failed file) and the deriver's opening messages; or, when a rotation could not open its
        file, that file now. False when there is no room yet."""
        if self._unopened is not None:
            path, header = self._unopened
        elif self._header is not None:
            path, header = self._stream, json.loads(self._header)
            if isinstance(header.get("file"), dict):
                header["file"] = {**header["file"], "previous": self._path.name, "continues": True}
        else:
            return False
        self._finish()  # what the failed file holds stays readable up to the failure
        try:
            file = _create(
                path,
                chunk_size=self._chunk_size,
                compression=self._compression,
                disk=self.disk,
                log_time_ns=log_time_ns,
            )
        except RecordingError:
            return False
        self._unopened = None
        previous = self._path
        with self._lock:
            self._file = file
            self._path = file.path
            self._paths.append(file.path)
        self._restored(file.path)
        log.info("recording_continued", path=str(file.path), previous=str(previous))
        self._handle(_Item(HEADER_TOPIC, log_time_ns, _encode(HEADER_TOPIC, header)))
        self._flush()
        return True

    def _restored(self, path: Path) -> None:
        with self._lock:
            self.failure = None
            self._broken = False
            self._retry_at_ns = None
        log.info("recording_restored", path=str(path), dropped=self.dropped)
        self._health(path, None)

    def _flush(self) -> None:
        if self._file is None or self.failure is not None:
            return
        try:
            self._file.writer.flush()  # type: ignore[no-untyped-call]  # mcap leaves it unannotated
            self._file.file.flush()
            self._settle()
        except Exception as e:  # the disk failed: keep the robot running, say so once
            self._fail(e)

    def _settle(self) -> None:
        """Everything given to the MCAP writer so far is now in the file: count it as written."""
        with self._lock:
            self._written += self._unflushed
            self._unflushed = 0

    def _fail(self, error: BaseException, *, broken: bool = True) -> None:
        """Stop writing after a disk or encoder error until there is room again; what is not in the file
        counts as dropped. ``broken``: the file cannot be continued (the error may have cut a record)."""
        with self._lock:
            self.failure = error
            self._broken = broken
            self._retry_at_ns = None
            if broken:
                self._dropped += self._unflushed
                self._unflushed = 0
        log.error("recording_failed", path=str(self._path), error=str(error))
        self._health(self._path, str(error))
        if self._file is not None:
            with contextlib.suppress(OSError, ValueError):
                self._file.file.flush()

    def _switch(self, rotate: _Rotate) -> None:
        """Finish the current file and open the next one with its header and the opening messages."""
        previous = self._path.name
        self._finish()
        self._thin_hz = rotate.thin_hz
        self._last_kept = {}
        try:
            file = _create(
                rotate.path,
                chunk_size=self._chunk_size,
                compression=self._compression,
                disk=self.disk,
                log_time_ns=rotate.log_time_ns,
            )
        except RecordingError as e:
            self._unopened = (rotate.path, _with_previous(rotate.header, previous))  # tried again later
            self._stream = rotate.path
            with self._lock:
                self._file = None
                self._broken = True
                self._retry_at_ns = rotate.log_time_ns + self._retry_ns
                already = self.failure is not None
                self.failure = e
            if already:  # said once per failure, however many rotations fail meanwhile
                return
            log.error("recording_failed", path=str(rotate.path), error=str(e))
            self._health(rotate.path, str(e))
            return
        self._stream = rotate.path
        with self._lock:
            self._file = file
            self._path = file.path
            self._paths.append(file.path)
            failed = self.failure is not None
        if failed:
            self._restored(file.path)
        log.info("recording_rotated", path=str(file.path), thin_hz=rotate.thin_hz)
        header = _with_previous(rotate.header, previous)
        self._handle(_Item(HEADER_TOPIC, rotate.log_time_ns, _encode(HEADER_TOPIC, header)))
        self._flush()
        if rotate.on_open is not None:
            try:
                rotate.on_open(file.path)
            except Exception as e:  # retention failing must not stop the recording
                log.error("recording_retention_failed", error=repr(e))

    def _health(self, path: Path, error: str | None) -> None:
        if self._on_health is None:
            return
        try:
            self._on_health(path, error)
        except Exception as e:  # the listener failing must not stop the recording
            self._warn_once("health", "recording_listener_failed", error=repr(e))

    def _finish(self) -> None:
        file = self._file
        if file is None:
            return
        try:
            if self.failure is None or not self._broken:
                file.writer.finish()  # type: ignore[no-untyped-call]  # mcap leaves it unannotated
                self._settle()
        except Exception as e:  # a failing disk at the very end still leaves a readable, truncated file
            self._fail(e)
        finally:
            with contextlib.suppress(OSError):
                file.file.close()
            with self._lock:
                self._bytes_done += file.size()
                self._file = None


def header_payload(
    config: Mapping[str, object],
    scene: Mapping[str, object],
    *,
    job: Mapping[str, object] | None = None,
    file: Mapping[str, object] | None = None,
    clock: Mapping[str, object] | None = None,
) -> dict[str, object]:
    """The ``session/header`` message: ``config`` and ``scene``, plus ``job``, ``file`` and ``clock`` when
    given."""
    payload: dict[str, object] = {"config": dict(config), "scene": dict(scene)}
    if clock is not None:
        payload["clock"] = dict(clock)
    if job is not None:
        payload["job"] = dict(job)
    if file is not None:
        payload["file"] = dict(file)
    return payload


def _with_previous(header: Mapping[str, object], previous: str | None) -> dict[str, object]:
    """A rotation's header with ``file.previous`` naming the file before it."""
    out = dict(header)
    file = out.get("file")
    if isinstance(file, Mapping):
        out["file"] = {**file, "previous": previous}
    return out


def _create(
    path: Path, *, chunk_size: int, compression: CompressionType, disk: DiskSpace, log_time_ns: int
) -> _File:
    return _File(
        free_path(path), chunk_size=chunk_size, compression=compression, disk=disk, log_time_ns=log_time_ns
    )


def free_path(path: Path) -> Path:
    """``path``, or ``path`` with ``-1``, ``-2``, ... before the suffix when that is taken."""
    for i in range(_MAX_NAME_TRIES):
        candidate = path if i == 0 else path.with_name(f"{path.stem}-{i}{path.suffix}")
        if not candidate.exists():
            return candidate
    raise RecordingError(f"recording {path} and {_MAX_NAME_TRIES - 1} numbered variants already exist")


def _encode(topic: str, payload: Payload) -> bytes:
    if not topic:
        raise RecordingError("recording topic must be a non-empty key expression")
    if not isinstance(payload, Mapping | Message):
        raise RecordingError(
            f"recording payload for {topic!r} must be a JSON object, got {type(payload).__name__}"
        )
    try:
        return encode(payload)
    except (TypeError, ValueError) as e:
        raise RecordingError(f"recording payload for {topic!r} is not JSON: {e}") from e


# Open by nature (wire.messages): a deriver gets their JSON object, every key of it.
_OPEN_TOPICS: Final = frozenset({"events", "log"})


def _decoded(topic: str, data: bytes) -> Mapping[str, object] | Message:
    """A recorded message for a deriver: its declared type when it has one (decoded straight from the
    bytes), else its JSON object."""
    suffix = topic_suffix(topic)
    kind = None if suffix in _OPEN_TOPICS else message_type(topic)
    if kind is None:
        doc = json.loads(data)
        if not isinstance(doc, dict):
            raise ValueError(f"{suffix}: not a JSON object")
        return doc
    return decode(data, kind, name=suffix)


def _check_time(topic: str, log_time_ns: object) -> None:
    if isinstance(log_time_ns, bool) or not isinstance(log_time_ns, int) or not 0 <= log_time_ns < 2**64:
        raise RecordingError(f"recording log_time_ns for {topic!r} must be an integer in [0, 2**64)")


def _check_thin(thin_hz: float | None) -> None:
    if thin_hz is not None and not 0.0 < thin_hz <= 1000.0:
        raise RecordingError(f"recording thin_hz {thin_hz} is out of range (0, 1000] Hz")
