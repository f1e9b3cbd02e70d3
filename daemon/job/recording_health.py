"""The session's recording as the job sees it: its health for ``status``, the messages it lost during the
job for the summary, and its failures and recoveries published on ``events`` (``recording_failed``,
``recording_restored``). The job carries on either way: a robot that loses its recording is still safe."""

from __future__ import annotations

from typing import Protocol

from daemon.job.services import Services
from wire.messages import RecordingFailedEvent, RecordingRestoredEvent


class RecordingHealth(Protocol):
    """What the job asks of the session's recording (``recorder.SessionRecording``)."""

    def dropped(self) -> int: ...

    def health(self) -> dict[str, object]: ...


class RecordingWatch:
    """The job's view of ``recording`` (None: the job records nothing)."""

    def __init__(self, services: Services, recording: RecordingHealth | None) -> None:
        self._services = services
        self._recording = recording
        self._dropped_before = 0  # the recording's losses when the job started

    def job_started(self) -> None:
        """A job starts now: its losses are counted from here."""
        self._dropped_before = self._recording.dropped() if self._recording is not None else 0

    def dropped_since_start(self) -> int | None:
        """The messages the recording lost since the job started (None: the job records nothing)."""
        return self._recording.dropped() - self._dropped_before if self._recording is not None else None

    def health(self) -> dict[str, object] | None:
        """The recording's health for ``status`` (None: the job records nothing)."""
        return self._recording.health() if self._recording is not None else None

    def report(self, path: str, error: str | None) -> None:
        """Writing the recording failed (``error``) or works again (None): published on ``events``."""
        if error is not None:
            dropped = self._recording.dropped() if self._recording is not None else 0
            self._services.event(RecordingFailedEvent(path=path, error=error, dropped=dropped))
        else:
            self._services.event(RecordingRestoredEvent(path=path))
