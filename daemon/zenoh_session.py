"""The daemon's one Zenoh session: publishers for its key space, the command queryable, the liveliness token.

Key space (``dishbot/<robot_id>/`` + topic): ``state``, ``joints``, ``gripper``, ``detections``, ``plan``,
``events``, ``log`` are published as JSON; ``cmd/<verb>`` are queryables answering JSON; ``alive`` is a
liveliness token. Everything published is also written to the session's recording under the same key.

A query may name many robots (``dishbot/*/cmd/status``): Zenoh delivers it to every queryable whose key
intersects it, so the verb is found by intersecting the query with this robot's own command keys, never by
cutting the robot id out of the query. Every reply is sent on this robot's own concrete key and carries its
``robot_id``.

Zenoh calls the query callback on its own threads; the callback only checks the payload size and hands the
query to the event loop with ``call_soon_threadsafe``. Replies are sent from a worker thread, so a congested
link never stalls the loop. Every query is finished (replied and dropped), also when the handler fails.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import re
import threading
from collections.abc import Awaitable, Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import structlog
import zenoh

from daemon.security import NAMESPACE, ZenohConfig, node_settings
from wire.messages import Payload
from wire.messages import encode as wire_encode

log = structlog.get_logger("daemon.zenoh")

TOPICS = ("state", "joints", "gripper", "detections", "plan", "events", "log")

# handler(verb, payload, many): ``many`` is true when the query was addressed to more than this robot.
CommandHandler = Callable[[str, bytes, bool], Awaitable[dict[str, object]]]
ConnectionListener = Callable[[int, int], None]  # (peers, routers) connected now, called on the loop

# Reconnecting to `connect` endpoints: first retry after 0.5 s, doubling up to 4 s, for ever.
_RETRY = {"period_init_ms": 500, "period_max_ms": 4000, "period_increase_factor": 2}


class RecordSink(Protocol):
    """What the session records to: ``recorder.Recorder`` fits."""

    def write(self, topic: str, payload: Payload, *, log_time_ns: int, data: bytes | None = None) -> bool: ...


def session_config(
    *,
    listen: Sequence[str],
    connect: Sequence[str],
    mode: str = "peer",
    settings: Mapping[str, object] | None = None,
) -> zenoh.Config:
    """Explicit endpoints, no multicast scouting and no gossip: peers find each other only through
    ``listen``/``connect``. Peers and routers retry their ``connect`` endpoints with backoff for ever; a
    client fails at once when it cannot connect. ``settings`` are further Zenoh keys (security, limits)."""
    config = zenoh.Config()
    entries: dict[str, object] = {
        "mode": mode,
        "scouting/multicast/enabled": False,
        "scouting/gossip/enabled": False,
        "listen/endpoints": list(listen),
        "connect/endpoints": list(connect),
    }
    entries["connect/retry"] = _RETRY  # a client, once open, reconnects after a lost link too
    if mode != "client":
        entries |= {"connect/timeout_ms": -1, "connect/exit_on_failure": False}
    entries |= dict(settings or {})
    for name, value in entries.items():
        config.insert_json5(name, json.dumps(value))
    return config


def transport_limit_bytes(max_command_bytes: int) -> int:
    """The largest message Zenoh reassembles for the daemon. Messages up to one batch (64 KiB) arrive whole
    and meet the handler's exact limit; anything larger is dropped fragment by fragment once past this, so a
    peer cannot make the daemon buffer a huge payload before it is refused."""
    return max(64 * 1024, 2 * max_command_bytes + 4096)


def error_text(e: zenoh.ZError) -> str:
    """Zenoh's error message without the Rust source locations it carries (`` at /.../x.rs:12.``)."""
    return re.sub(r"\s+at \S+\.rs:\d+\.?", "", str(e)).strip()


def key(robot_id: str, topic: str) -> str:
    return f"{NAMESPACE}/{robot_id}/{topic}"


def encode(payload: Mapping[str, object]) -> bytes:
    """Compact JSON; values JSON cannot hold (numpy scalars, paths) are written as their ``str``."""
    return json.dumps(payload, separators=(",", ":"), default=str, allow_nan=False).encode()


@dataclass(frozen=True, slots=True)
class Addressed:
    """Which command a query asks this robot for; ``error`` when it names none or several."""

    verb: str
    many: bool
    reply_key: str
    error: str | None = None


def addressed(query_key: str, robot_id: str, verbs: Sequence[str]) -> Addressed:
    """The command ``query_key`` asks ``robot_id`` for (Zenoh delivered it because the keys intersect).

    ``many`` is true when the query names robots by wildcard (``dishbot/*/cmd/status``); a verb outside
    ``verbs`` written out in full is passed on, so the handler can say it is unknown."""
    own = key(robot_id, "cmd/")
    many = not query_key.startswith(f"{NAMESPACE}/{robot_id}/")
    parts = query_key.split("/", 3)
    literal = parts[3] if len(parts) == 4 and parts[2] == "cmd" and not _wild(parts[3]) else None
    if literal is not None and (not many or literal not in verbs):
        return Addressed(literal, many, own + literal)
    query = zenoh.KeyExpr(query_key)
    matching = [v for v in verbs if query.intersects(zenoh.KeyExpr(own + v))]
    if len(matching) == 1:
        return Addressed(matching[0], many, own + matching[0])
    what = "no command" if not matching else f"{len(matching)} commands ({', '.join(matching)})"
    return Addressed("", many, "", f"the query {query_key} names {what}; ask for one cmd/<verb>")


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
        self._listener: Any = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._handler: CommandHandler | None = None
        self._verbs: tuple[str, ...] = ()
        self._tasks: set[asyncio.Task[None]] = set()
        self._transports: dict[str, bool] = {}  # zid -> is a router, for peers and routers connected now
        # Publishing may come from any thread; closing must not overlap a put (zenoh-python refuses a
        # session borrowed twice: "Already borrowed"), and nothing is put once closed.
        self._put_lock = threading.Lock()
        self._closed = False

    @classmethod
    def open(
        cls,
        robot_id: str,
        *,
        listen: Sequence[str],
        connect: Sequence[str],
        max_command_bytes: int,
        zenoh_config: ZenohConfig | None = None,
    ) -> ZenohSession:
        """Open the session; raises ``zenoh.ZError`` when an endpoint cannot be listened on."""
        settings: dict[str, object] = {
            "transport/link/rx/max_message_size": transport_limit_bytes(max_command_bytes),
            # A command travels as ordinary bytes, so the transport's size limit applies to it too.
            "transport/shared_memory/enabled": False,
        }
        if zenoh_config is not None:
            settings |= node_settings(zenoh_config)
        session = zenoh.open(session_config(listen=listen, connect=connect, settings=settings))
        return cls(session, robot_id, max_command_bytes=max_command_bytes)

    def key(self, topic: str) -> str:
        return key(self.robot_id, topic)

    def attach_recorder(self, recorder: RecordSink | None, now_ns: Callable[[], int] | None = None) -> None:
        """Also write everything published (and ``record``-ed) to ``recorder``, stamped with ``now_ns()``
        (the session clock's ``now`` in nanoseconds); None detaches."""
        if recorder is not None and now_ns is None:
            raise ValueError("attach_recorder needs now_ns: the session clock the messages are stamped on")
        self._recorder, self._now_ns = recorder, now_ns

    def publish(self, topic: str, payload: Payload) -> None:
        """Publish on ``dishbot/<id>/<topic>`` and record it, the same bytes to both (encoded once, by
        ``wire.messages.encode``); safe from any thread."""
        data = wire_encode(payload)
        self._record(self.key(topic), payload, data)
        with self._put_lock:
            if self._closed:  # a late message (a recorder's health report at shutdown): recorded only
                return
            publisher = self._publishers.get(topic)
            if publisher is None:
                self.session.put(self.key(topic), data)
            else:
                publisher.put(data)

    def record(self, topic: str, payload: Payload) -> None:
        """Record without publishing (driver-boundary inputs), under ``dishbot/<id>/<topic>``."""
        self._record(self.key(topic), payload, None)

    def _record(self, topic: str, payload: Payload, data: bytes | None) -> None:
        recorder, now_ns = self._recorder, self._now_ns
        if recorder is not None and now_ns is not None:
            recorder.write(topic, payload, log_time_ns=now_ns(), data=data)

    def serve(
        self, loop: asyncio.AbstractEventLoop, handler: CommandHandler, *, verbs: Sequence[str]
    ) -> None:
        """Answer ``cmd/<verb>`` queries with ``handler(verb, payload, many)`` on ``loop``; announce
        liveliness."""
        self._loop = loop
        self._handler = handler
        self._verbs = tuple(verbs)
        self._queryable = self.session.declare_queryable(self.key("cmd/**"), self._on_query)
        self._token = self.session.liveliness().declare_token(self.key("alive"))

    def watch_connections(self, loop: asyncio.AbstractEventLoop, listener: ConnectionListener) -> None:
        """Call ``listener(peers, routers)`` on ``loop`` whenever a peer or router connects or goes away
        (clients, such as the command-line verbs, are not counted)."""

        def changed(opened: bool, zid: str, router: bool) -> None:
            if opened:
                self._transports[zid] = router
            else:
                self._transports.pop(zid, None)
            routers = sum(self._transports.values())
            listener(len(self._transports) - routers, routers)

        def on_event(event: zenoh.TransportEvent) -> None:  # on a Zenoh thread
            transport = event.transport
            if transport.whatami not in (zenoh.WhatAmI.PEER, zenoh.WhatAmI.ROUTER):
                return
            opened = event.kind == zenoh.SampleKind.PUT
            router = transport.whatami == zenoh.WhatAmI.ROUTER
            with contextlib.suppress(RuntimeError):  # the loop is closed: the daemon is gone
                loop.call_soon_threadsafe(changed, opened, str(transport.zid), router)

        self._listener = self.session.info.declare_transport_events_listener(on_event, history=True)
        # After the history (queued above, as every event is): a first report even when nothing is connected.
        loop.call_soon_threadsafe(changed, False, "", False)

    def close(self) -> None:
        """Undeclare everything and close the session (once; later publishes are only recorded)."""
        with self._put_lock:
            if self._closed:
                return
            self._closed = True
            for entity in (self._listener, self._token, self._queryable, *self._publishers.values()):
                if entity is not None:
                    entity.undeclare()
            self._listener = self._token = self._queryable = None
            self._publishers = {}
        self.session.close()  # type: ignore[no-untyped-call]

    # --- called on a Zenoh thread ---------------------------------------------------------------------------

    def _on_query(self, query: zenoh.Query) -> None:
        target = addressed(str(query.key_expr), self.robot_id, self._verbs)
        payload = query.payload.to_bytes() if query.payload is not None else b""
        loop = self._loop
        if target.error is not None:
            self._finish(query, target, {"ok": False, "error": target.error})
        elif len(payload) > self._max_command_bytes:
            self._finish(
                query, target, {"ok": False, "error": _too_big(len(payload), self._max_command_bytes)}
            )
        elif loop is None or loop.is_closed():
            self._finish(query, target, {"ok": False, "error": "the daemon is shutting down"})
        else:
            try:
                loop.call_soon_threadsafe(self._dispatch, query, target, payload)
            except RuntimeError:
                self._finish(query, target, {"ok": False, "error": "the daemon is shutting down"})

    def _finish(self, query: zenoh.Query, target: Addressed, reply: Mapping[str, object]) -> None:
        """Reply (on this robot's own key, with its id) and drop the query; any thread, never raises."""
        body = encode({"robot_id": self.robot_id, **reply})
        try:
            if target.reply_key:
                query.reply(target.reply_key, body)
            else:  # the query names no single command: no key of ours answers it
                query.reply_err(body)
        except zenoh.ZError as e:
            log.warning("reply_failed", key=str(query.key_expr), error=str(e))
        finally:
            query.drop()  # type: ignore[no-untyped-call]

    # --- on the event loop ---------------------------------------------------------------------------------

    def _dispatch(self, query: zenoh.Query, target: Addressed, payload: bytes) -> None:
        task = asyncio.get_running_loop().create_task(self._answer(query, target, payload))
        self._tasks.add(task)
        task.add_done_callback(self._tasks.discard)

    async def _answer(self, query: zenoh.Query, target: Addressed, payload: bytes) -> None:
        reply: dict[str, object]
        try:
            assert self._handler is not None
            reply = await self._handler(target.verb, payload, target.many)
        except Exception as e:  # the querier must get an answer whatever went wrong
            log.exception("command_crashed", verb=target.verb)
            reply = {"ok": False, "error": f"internal error handling {target.verb}: {e!r}"}
        # Sending may wait on a congested link: never on the loop that drives the arm.
        await asyncio.get_running_loop().run_in_executor(None, self._finish, query, target, reply)


def _wild(chunk: str) -> bool:
    return "*" in chunk or "$" in chunk


def _too_big(size: int, limit: int) -> str:
    return f"payload of {size} bytes is larger than the limit of {limit} bytes"
