"""Which file a message goes to: a file per job, idle files between jobs, and the retention limits.

``SessionRecording`` stands between the daemon and its ``Recorder``: it sees every message in the order the
daemon publishes it and rotates the recorder at the right point of the stream.

- A job's ``start`` transition opens a new job file; its header names what the job runs (dataset or mugs,
  planner settings, seeds: ``expect_job``). The job file ends ``job_tail_s`` after the job did (done,
  fault, estop, or stopped back to idle), so the final state and the arm coming to rest are in it.
- The time between jobs goes to idle files, a new one every ``idle_file_s``; they keep the high-rate
  telemetry at ``idle_telemetry_hz``.
- After each new file, the oldest recordings of this robot are deleted while the directory holds more than
  ``max_total_mb`` or they are older than ``max_age_days`` (never a file some recorder is still writing).

File names are ``<robot_id>-<UTC start>-<job|idle>.mcap``, the start taken from the log time of the message
that opened the file. File ages for retention are the files' modification times against the wall clock:
they are facts of the file system, not of the robot's clock.
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Final

import structlog

from recorder.errors import RecordingError
from recorder.reader import being_written
from recorder.settings import RecordingConfig
from recorder.writer import (
    Deriver,
    DiskSpace,
    HealthListener,
    Recorder,
    RecorderStats,
    Tee,
    free_path,
    header_payload,
)
from wire.messages import (
    UNSET,
    BadMessage,
    Event,
    HeaderJob,
    HeaderScene,
    Message,
    Payload,
    as_message,
    header_part,
)
from wire.schemas import topic_suffix

log = structlog.get_logger(__name__)

JOB: Final = "job"
IDLE: Final = "idle"
_END_STATES: Final = frozenset({"done", "fault", "estop"})


def ends_job(transition: Event) -> bool:
    """Whether a ``transition`` event ends a loading job: done, fault, estop, or stopped back to idle."""
    dest = transition.dest
    return dest in _END_STATES or (dest == "idle" and transition.trigger == "stop")


def _transition(topic: str, payload: Payload) -> Event | None:
    """The transition ``payload`` is, when it is one (an ``events`` message of kind ``transition``)."""
    if topic_suffix(topic) != "events":
        return None
    try:
        event = as_message(payload, Event, name="events")
    except BadMessage:
        return None
    return event if event.kind == "transition" else None


def file_name(robot_id: str, kind: str, log_time_ns: int) -> str:
    """``<robot_id>-<UTC start, ms>-<kind>.mcap``."""
    stamp = datetime.fromtimestamp(log_time_ns // 1_000_000 / 1000.0, tz=UTC)
    return f"{robot_id}-{stamp.strftime('%Y%m%dT%H%M%S')}.{stamp.microsecond // 1000:03d}Z-{kind}.mcap"


def is_job_file(path: Path) -> bool:
    """Whether a recording file (named by ``file_name``) holds a job, rather than idle time."""
    tail = path.stem.rsplit("Z-", 1)[-1]  # the kind, and a -N a name clash added
    return tail == JOB or tail.startswith(f"{JOB}-")


@dataclass(frozen=True, slots=True)
class Retention:
    """How much of a recording directory to keep; 0 means no limit."""

    max_total_bytes: int
    max_age_s: float

    @classmethod
    def of(cls, settings: RecordingConfig) -> Retention:
        return cls(settings.max_total_mb * 1_000_000, settings.max_age_days * 86400.0)

    def apply(self, directory: Path, robot_id: str, *, keep: Path | None = None) -> list[Path]:
        """Delete this robot's oldest recordings past the limits; returns what was deleted."""
        if not self.max_total_bytes and not self.max_age_s:
            return []
        files = []
        for path in directory.glob(f"{robot_id}-*.mcap"):
            try:
                st = path.stat()
            except OSError:
                continue
            files.append((st.st_mtime, st.st_size, path))
        files.sort()
        total = sum(size for _, size, _ in files)
        now = time.time()
        deleted = []
        for mtime, size, path in files:
            too_old = bool(self.max_age_s) and now - mtime > self.max_age_s
            too_much = bool(self.max_total_bytes) and total > self.max_total_bytes
            if not (too_old or too_much):
                break
            if path == keep or being_written(path):
                continue
            try:
                path.unlink()
            except OSError as e:
                log.warning("recording_not_deleted", path=str(path), error=e.strerror)
                continue
            total -= size
            deleted.append(path)
            log.info("recording_deleted", path=str(path), bytes=size, reason="age" if too_old else "size")
        return deleted


class SessionRecording:
    """The daemon's recording: a ``Recorder`` rotated into job and idle files as the session goes.

    ``write`` has the signature of ``Recorder.write`` (the Zenoh session records through it) and is safe from
    any thread. The first file opens with the first message, stamped with that message's log time (so every
    time in a file comes from the clock the caller stamps messages with): a job file when ``job`` says what
    the job about to start runs (``--once``), else an idle file. ``scene`` gives the scene for a new file's
    header, ``config`` is the effective config, ``clock`` the session's clock as every header records it
    (``SessionClock.describe()``: its source and its wall-clock start).

    A disk that fails (full, gone) never stops the robot: what cannot be written is counted (``dropped``),
    ``health`` says what failed, the listener given to ``on_health`` hears of each failure and recovery,
    and writing goes on as soon as there is room (``Recorder``).

    ``lossless`` (simulated time): no message is dropped for a full queue; the clock holds time back while
    ``caught_up`` says the writer is behind.
    """

    def __init__(
        self,
        settings: RecordingConfig,
        directory: Path,
        robot_id: str,
        *,
        config: Mapping[str, object],
        scene: Callable[[], Mapping[str, object]],
        job: Mapping[str, object] | None = None,
        clock: Mapping[str, object] | None = None,
        deriver: Deriver | None = None,
        tee: Tee | None = None,
        lossless: bool = False,
    ) -> None:
        self._settings = settings
        self._lossless = lossless
        self._clock = dict(clock) if clock is not None else None
        self._directory = directory
        self._robot_id = robot_id
        self._config = dict(config)
        self._scene = scene
        self._deriver = deriver
        self._tee = tee
        self._retention = Retention.of(settings)
        # Re-entrant: opening a file logs, and the log record comes back here through the `log` topic.
        self._lock = threading.RLock()
        self._first_job = dict(job) if job is not None else None
        self._kind = JOB if job is not None else IDLE
        self._opened_ns = 0
        self._job_started = False
        self._job_ended_ns: int | None = None
        self._expected: Mapping[str, object] | None = None
        self._index = 0
        self._recorder: Recorder | None = None
        self._unusable = False
        self._opening = False
        self._early: list[tuple[str, Payload, int]] = []
        self.disk = DiskSpace()  # shared by every file of the session (a full disk stays full across them)
        self._listener: HealthListener | None = None
        self._failure: tuple[Path, str] | None = None  # the file that failed and why, until one works again

    @property
    def recorder(self) -> Recorder | None:
        """The recorder, once the first message opened the first file."""
        with self._lock:
            return self._recorder

    @property
    def path(self) -> Path | None:
        """The file being written now (None before the first message)."""
        recorder = self.recorder
        return recorder.path if recorder is not None else None

    def files(self) -> tuple[Path, ...]:
        """Every file opened so far, in order."""
        recorder = self.recorder
        return recorder.paths if recorder is not None else ()

    def on_health(self, listener: HealthListener) -> None:
        """Call ``listener(path, error)`` when writing a file fails, ``listener(path, None)`` when a new file
        is written again; from the recorder's thread or the caller's (it must not block)."""
        self._listener = listener

    def caught_up(self, wait_s: float = 0.0) -> bool:
        """Whether the recorder's writer has caught up with the messages handed to it, waiting up to
        ``wait_s`` seconds (``Recorder.caught_up``; before the first file, it has)."""
        recorder = self.recorder
        return recorder.caught_up(wait_s) if recorder is not None else True

    def dropped(self) -> int:
        """Messages that could not be recorded so far (disk failed, queue full)."""
        recorder = self.recorder
        return recorder.dropped if recorder is not None else 0

    def health(self) -> dict[str, object]:
        """For ``status``: whether recording works, the file and error of a failure, the messages lost."""
        failure = self._failure
        out: dict[str, object] = {"ok": failure is None, "path": str(self.path) if self.path else None}
        if failure is not None:
            out |= {"path": str(failure[0]), "error": failure[1]}
        return {**out, "dropped": self.dropped()}

    def _health_changed(self, path: Path, error: str | None) -> None:
        self._failure = None if error is None else (path, error)
        if self._listener is not None:
            self._listener(path, error)

    def apply_retention(self) -> list[Path]:
        """Delete recordings past the limits now (blocking: from the event loop, call it in a thread)."""
        return self._retention.apply(self._directory, self._robot_id, keep=self.path)

    def expect_job(self, job: Mapping[str, object]) -> None:
        """What the next job to start runs (its ``start`` request), for its file's header."""
        with self._lock:
            self._expected = dict(job)

    def write(self, topic: str, payload: Payload, *, log_time_ns: int, data: bytes | None = None) -> bool:
        """Record one message, first opening a new file when this message starts one; ``data`` are its
        bytes when already encoded (``Recorder.write``)."""
        with self._lock:
            if self._opening:  # a log record of the first file's opening, on this thread: after the header
                self._early.append(
                    (topic, payload if isinstance(payload, Message) else dict(payload), log_time_ns)
                )
                return True
            recorder = self._recorder
            if recorder is None:
                recorder = self._open_first(log_time_ns)
                if recorder is None:
                    return False
            self._route(topic, payload, log_time_ns)
        return recorder.write(topic, payload, log_time_ns=log_time_ns, data=data)

    def close(self) -> RecorderStats | None:
        """Finish the current file (blocking: from the event loop, call it in a thread)."""
        recorder = self.recorder
        return recorder.close() if recorder is not None else None

    def _open_first(self, t: int) -> Recorder | None:
        self._opening = True
        try:
            recorder = self._open(t)
        finally:
            self._opening = False
        early, self._early = self._early, []
        if recorder is not None:
            for topic, payload, log_time_ns in early:
                recorder.write(topic, payload, log_time_ns=log_time_ns)
        return recorder

    def _open(self, t: int) -> Recorder | None:
        if self._unusable:
            return None
        path = self._directory / file_name(self._robot_id, self._kind, t)
        try:
            recorder = Recorder(
                free_path(path),
                chunk_size=self._settings.chunk_size_bytes,
                compression=self._settings.compression,
                thin_hz=self._thin_hz(self._kind),
                deriver=self._deriver,
                tee=self._tee,
                disk=self.disk,
                on_health=self._health_changed,
                lossless=self._lossless,
            )
        except RecordingError as e:  # the robot keeps running without a recording; said once
            self._unusable = True
            log.error("recording_failed", path=str(path), error=str(e))
            self._health_changed(path, str(e))
            return None
        job = self._job_header(self._first_job) if self._first_job is not None else None
        recorder.write_header(
            self._config,
            self._scene(),
            log_time_ns=t,
            job=job,
            file=self._file_header(self._kind),
            clock=self._clock,
        )
        self._opened_ns = t
        self._recorder = recorder
        return recorder

    def _route(self, topic: str, payload: Payload, t: int) -> None:
        transition = _transition(topic, payload)
        if transition is not None and transition.trigger == "start":
            if self._kind == JOB and not self._job_started:
                self._job_started = True  # the file was opened for this job (--once)
            else:
                self._rotate(JOB, t)
                self._job_started = True
            return
        if self._kind == JOB:
            if transition is not None and self._job_ended_ns is None and ends_job(transition):
                self._job_ended_ns = t
            elif self._job_ended_ns is not None and t - self._job_ended_ns >= self._settings.job_tail_s * 1e9:
                self._rotate(IDLE, t)
        elif t - self._opened_ns >= self._settings.idle_file_s * 1e9:
            self._rotate(IDLE, t)

    def _rotate(self, kind: str, t: int) -> None:
        recorder = self._recorder
        assert recorder is not None
        job = self._job_header(self._expected or {}) if kind == JOB else None
        self._expected = None
        self._kind = kind
        self._opened_ns = t
        self._job_started = False
        self._job_ended_ns = None
        path = self._directory / file_name(self._robot_id, kind, t)
        header = header_payload(
            self._config, self._scene(), job=job, file=self._file_header(kind), clock=self._clock
        )
        try:
            recorder.rotate(
                path, header, log_time_ns=t, thin_hz=self._thin_hz(kind), on_open=self._after_open
            )
        except RecordingError as e:  # the robot keeps running; the stream stays in the file it was in
            log.error("recording_rotation_failed", path=str(path), error=str(e))

    def _after_open(self, path: Path) -> None:
        self._retention.apply(self._directory, self._robot_id, keep=path)

    def _thin_hz(self, kind: str) -> float | None:
        return self._settings.idle_telemetry_hz if kind == IDLE else None

    def _job_header(self, job: Mapping[str, object]) -> dict[str, object]:
        out = dict(job)
        asked = header_part(job, HeaderJob)
        if asked.dataset in (None, UNSET) and asked.mugs in (None, UNSET):
            dataset = header_part(self._scene(), HeaderScene).dataset
            out["dataset"] = None if dataset is UNSET else dataset  # the same scene as the job before
        return out

    def _file_header(self, kind: str) -> dict[str, object]:
        """The header's ``file``: its kind and number in this process, the writer's pid, the file before it
        (filled in by the recorder when it switches files)."""
        self._index += 1
        return {"kind": kind, "index": self._index, "pid": os.getpid(), "previous": None}
