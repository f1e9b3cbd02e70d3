"""Where the daemon's log lines go: the process's output, guarded, and the planning worker's records relayed.

A dead output (``| head`` that has exited, a ``| tee`` killed by Ctrl-C, a closed terminal) must never change
what the daemon does: ``output_guarded`` makes structlog's output drop a line it cannot write and count it
(``LostLines``) instead of raising into whatever was logging. The records still reach ``log`` and the
recording, which do not go through the output.

The worker logs to its own stderr as before, guarded the same way; ``forward_to(queue)`` adds a structlog
processor there that also puts a plain copy of each record (at or above the worker's level, which is the
daemon's) on a queue. ``LogRelay`` drains that queue on a thread of the daemon and hands each record to a
callback (publishing it on ``log``, which records it). Nothing blocks on either side: a full queue drops the
record, and ``close`` returns within its bound whatever the queue does.
"""

from __future__ import annotations

import contextlib
import queue
import sys
import threading
import traceback
from collections.abc import Callable, Iterator, Mapping, MutableMapping
from typing import Any, Protocol

import structlog

_STOP = None


class RecordQueue(Protocol):
    """A ``multiprocessing`` queue of log records (the forkserver context's)."""

    def put_nowait(self, item: Any) -> None: ...

    def get(self, block: bool = True, timeout: float | None = None) -> Any: ...

    def put(self, item: Any, block: bool = True, timeout: float | None = None) -> None: ...


class LostLines:
    """How many log lines the process's output could not take (it was closed or broken). Thread-safe."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._count = 0

    @property
    def count(self) -> int:
        with self._lock:
            return self._count

    def add(self) -> None:
        with self._lock:
            self._count += 1


class _GuardedLogger:
    """A structlog logger (``PrintLogger`` and its kind) whose writes never raise: a line the output cannot
    take (a closed pipe, a closed file) is dropped and counted."""

    def __init__(self, inner: Any, lost: LostLines) -> None:
        self._inner = inner
        self._lost = lost

    def __getattr__(self, name: str) -> Any:
        method = getattr(self._inner, name)
        if not callable(method):
            return method

        def guarded(*args: Any, **kwargs: Any) -> Any:
            try:
                return method(*args, **kwargs)
            except (OSError, ValueError):  # EPIPE, EIO, ENOSPC; ValueError: I/O on a closed file
                self._lost.add()
                return None

        return guarded


def _guard(factory: Callable[..., Any], lost: LostLines) -> Callable[..., Any]:
    def guarded_factory(*args: Any) -> Any:
        return _GuardedLogger(factory(*args), lost)

    guarded_factory.lost = lost  # type: ignore[attr-defined]  # what an inner output_guarded counts on
    return guarded_factory


@contextlib.contextmanager
def output_guarded() -> Iterator[LostLines]:
    """While active, structlog's output drops and counts the lines it cannot write instead of raising.
    Inside another ``output_guarded`` (the command's set-up is guarded too, before the daemon starts), the
    outer guard and its count go on."""
    factory = structlog.get_config()["logger_factory"]
    outer = getattr(factory, "lost", None)
    if isinstance(outer, LostLines):
        yield outer
        return
    lost = LostLines()
    structlog.configure(logger_factory=_guard(factory, lost))
    try:
        yield lost
    finally:
        structlog.configure(logger_factory=factory)


def plain_record(event: Mapping[str, object], method: str) -> dict[str, object]:
    """A log record with JSON values only (anything else as its ``str``) and its level. A record logged with
    an exception (``log.exception(...)``, ``exc_info``) carries it as text: ``exception`` (type and message)
    and ``traceback``, so a reader far from the process can tell why."""
    record: dict[str, object] = {
        k: v if isinstance(v, str | int | float | bool | None) else str(v)
        for k, v in event.items()
        if k != "exc_info"
    }
    error = _exception(event.get("exc_info"))
    if error is not None:
        record["exception"] = "".join(traceback.format_exception_only(error)).strip()
        record["traceback"] = "".join(traceback.format_exception(error))
    record.setdefault("level", method)
    return record


def _exception(exc_info: object) -> BaseException | None:
    """The exception structlog's ``exc_info`` names: True (the one being handled), an exception or a
    ``sys.exc_info()`` tuple."""
    if exc_info is True:
        exc_info = sys.exc_info()
    if isinstance(exc_info, tuple) and len(exc_info) == 3:
        exc_info = exc_info[1]
    return exc_info if isinstance(exc_info, BaseException) else None


class _Forward:
    def __init__(self, records: RecordQueue, process: str) -> None:
        self.records = records
        self.process = process

    def __call__(
        self, logger: object, method: str, event: MutableMapping[str, Any]
    ) -> MutableMapping[str, Any]:
        with contextlib.suppress(Exception):  # logging must never take the worker down
            self.records.put_nowait({**plain_record(event, method), "process": self.process})
        return event


def forward_to(records: RecordQueue, *, process: str = "planning") -> None:
    """In a worker process: also put every structlog record on ``records`` (before the final renderer), and
    never raise for an output that went away (the daemon's stderr is the worker's: a closed pipe there must
    not fail a plan)."""
    config = structlog.get_config()
    processors = list(config["processors"])
    structlog.configure(
        processors=[*processors[:-1], _Forward(records, process), *processors[-1:]],
        logger_factory=_guard(config["logger_factory"], LostLines()),
    )


class LogRelay:
    """Hands the records put on ``records`` to ``deliver`` on a thread of its own, until ``close``."""

    def __init__(self, records: RecordQueue, deliver: Callable[[Mapping[str, object]], None]) -> None:
        self._records = records
        self._deliver = deliver
        self._thread = threading.Thread(target=self._run, name="log-relay", daemon=True)
        self._thread.start()

    def close(self, *, timeout_s: float = 2.0) -> None:
        """Stop relaying; returns within about ``timeout_s`` even when the queue is stuck (the thread is a
        daemon thread: it never holds the process's exit)."""
        with contextlib.suppress(Exception):
            self._records.put(_STOP, timeout=timeout_s / 2)
        self._thread.join(timeout=timeout_s / 2)

    def _run(self) -> None:
        while True:
            try:
                record = self._records.get(timeout=1.0)
            except queue.Empty:
                continue
            except (EOFError, OSError):  # the queue went away with the process
                return
            if record is _STOP:
                return
            if isinstance(record, Mapping):
                with contextlib.suppress(Exception):  # a failing delivery must not end the relay
                    self._deliver(record)
