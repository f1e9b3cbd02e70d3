"""The daemon's one Zenoh session: publishers for its key space, the command queryable, the liveliness token.

Key space (``dishbot/<robot_id>/`` + topic): ``state``, ``joints``, ``gripper``, ``detections``, ``plan``,
``events``, ``log`` are published as JSON; ``cmd/<verb>`` are queryables answering JSON; ``alive`` is a
liveliness token. Everything published is also written to the session's recording under the same key.

Zenoh calls the query callback on its own threads; the callback only checks the payload size and hands the
query to the event loop with ``call_soon_threadsafe``. Every query is finished (replied and dropped), also
when the handler fails.
"""

from __future__ import annotations

import asyncio
import json
from collections.abc import Awaitable, Callable, Mapping, Sequence
from typing import Any, Protocol

import structlog
import zenoh

log = structlog.get_logger("daemon.zenoh")

NAMESPACE = "dishbot"
TOPICS = ("state", "joints", "gripper", "detections", "plan", "events", "log")

CommandHandler = Callable[[str, bytes], Awaitable[dict[str, object]]]


class RecordSink(Protocol):
    """What the session records to: ``daemon.recording.Recorder`` fits."""

    def write(self, topic: str, payload: Mapping[str, object], *, log_time_ns: int) -> bool: ...


def session_config(*, listen: Sequence[str], connect: Sequence[str]) -> zenoh.Config:
    """Peer mode, multicast scouting off, explicit endpoints (the only way peers find each other)."""
    config = zenoh.Config()
    config.insert_json5("mode", '"peer"')
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("listen/endpoints", json.dumps(list(listen)))
    config.insert_json5("connect/endpoints", json.dumps(list(connect)))
    return config


def key(robot_id: str, topic: str) -> str:
    return f"{NAMESPACE}/{robot_id}/{topic}"


def encode(payload: Mapping[str, object]) -> bytes:
    """Compact JSON; values JSON cannot hold (numpy scalars, paths) are written as their ``str``."""
    return json.dumps(payload, separators=(",", ":"), default=str, allow_nan=False).encode()


class ZenohSession:
    """Publishing, recording and command serving for one robot id over one open session."""

    def __init__(self, session: zenoh.Session, robot_id: str, *, max_command_bytes: int) -> None:
        self.session = session
        self.robot_id = robot_id
        self._max_command_bytes = max_command_bytes
        self._publishers = {t: session.declare_publisher(key(robot_id, t)) for t in TOPICS}
        self._recorder: RecordSink | None = None
        self._now_ns: Callable[[], int] | None = None
        self._queryable: Any = None
        self._token: Any = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._handler: CommandHandler | None = None
        self._tasks: set[asyncio.Task[None]] = set()

    @classmethod
    def open(
        cls, robot_id: str, *, listen: Sequence[str], connect: Sequence[str], max_command_bytes: int
    ) -> ZenohSession:
        """Open the session; raises ``zenoh.ZError`` when an endpoint cannot be listened on."""
        session = zenoh.open(session_config(listen=listen, connect=connect))
        return cls(session, robot_id, max_command_bytes=max_command_bytes)

    def key(self, topic: str) -> str:
        return key(self.robot_id, topic)

    def attach_recorder(self, recorder: RecordSink | None, now_ns: Callable[[], int] | None = None) -> None:
        """Also write everything published (and ``record``-ed) to ``recorder``, stamped with ``now_ns()``
        (the session clock's ``now`` in nanoseconds); None detaches."""
        if recorder is not None and now_ns is None:
            raise ValueError("attach_recorder needs now_ns: the session clock the messages are stamped on")
        self._recorder, self._now_ns = recorder, now_ns

    def publish(self, topic: str, payload: Mapping[str, object]) -> None:
        """Publish on ``dishbot/<id>/<topic>`` and record it; safe from any thread."""
        data = encode(payload)
        self._record(self.key(topic), payload)
        publisher = self._publishers.get(topic)
        if publisher is None:
            self.session.put(self.key(topic), data)
        else:
            publisher.put(data)

    def record(self, topic: str, payload: Mapping[str, object]) -> None:
        """Record without publishing (driver-boundary inputs), under ``dishbot/<id>/<topic>``."""
        self._record(self.key(topic), payload)

    def _record(self, topic: str, payload: Mapping[str, object]) -> None:
        recorder, now_ns = self._recorder, self._now_ns
        if recorder is not None and now_ns is not None:
            recorder.write(topic, payload, log_time_ns=now_ns())

    def serve(self, loop: asyncio.AbstractEventLoop, handler: CommandHandler) -> None:
        """Answer ``cmd/<verb>`` queries with ``handler(verb, payload)`` on ``loop``; announce liveliness."""
        self._loop = loop
        self._handler = handler
        self._queryable = self.session.declare_queryable(self.key("cmd/**"), self._on_query)
        self._token = self.session.liveliness().declare_token(self.key("alive"))

    def close(self) -> None:
        """Undeclare everything and close the session."""
        for entity in (self._token, self._queryable, *self._publishers.values()):
            if entity is not None:
                entity.undeclare()
        self._token = self._queryable = None
        self._publishers = {}
        self.session.close()  # type: ignore[no-untyped-call]

    # --- called on a Zenoh thread ---------------------------------------------------------------------------

    def _on_query(self, query: zenoh.Query) -> None:
        verb = str(query.key_expr).removeprefix(self.key("cmd/"))
        payload = query.payload.to_bytes() if query.payload is not None else b""
        loop = self._loop
        if len(payload) > self._max_command_bytes:
            _finish(query, {"ok": False, "error": _too_big(len(payload), self._max_command_bytes)})
            return
        if loop is None or loop.is_closed():
            _finish(query, {"ok": False, "error": "the daemon is shutting down"})
            return
        try:
            loop.call_soon_threadsafe(self._dispatch, query, verb, payload)
        except RuntimeError:
            _finish(query, {"ok": False, "error": "the daemon is shutting down"})

    # --- on the event loop ---------------------------------------------------------------------------------

    def _dispatch(self, query: zenoh.Query, verb: str, payload: bytes) -> None:
        task = asyncio.get_running_loop().create_task(self._answer(query, verb, payload))
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    async def _answer(self, query: zenoh.Query, verb: str, payload: bytes) -> None:
        reply: dict[str, object]
        try:
            assert self._handler is not None
            reply = await self._handler(verb, payload)
        except Exception as e:  # the querier must get an answer whatever went wrong
            log.exception("command_crashed", verb=verb)
            reply = {"ok": False, "error": f"internal error handling {verb}: {e!r}"}
        _finish(query, reply)


def _too_big(size: int, limit: int) -> str:
    return f"payload of {size} bytes is larger than the limit of {limit} bytes"


def _finish(query: zenoh.Query, reply: Mapping[str, object]) -> None:
    try:
        query.reply(query.key_expr, encode(reply))
    except zenoh.ZError as e:
        log.warning("reply_failed", key=str(query.key_expr), error=str(e))
    finally:
        query.drop()  # type: ignore[no-untyped-call]
