"""The live Foxglove view: the Foxglove SDK's WebSocket server, fed with every channel the recorder writes.

The server is a ``recording.writer.Tee``: the recorder's thread hands it each message it handles (the header,
the JSON channels and the Foxglove channels derived from them), so the live view and the recording show the
same channels, the live one at the full rate even while idle files are thinned.

Every channel the daemon can record is declared when the server starts (``known_channels``: the header, a
JSON channel per topic ``wire.schemas`` describes, the Foxglove scene's channels), before any client
connects and before any message: a client sees them all in its first ``advertise``, subscribes, and misses
nothing from then on. A channel declared while clients were connected loses its first message to them (they
can only subscribe once it is advertised) and races their subscriptions; a topic nobody described (a test's,
a tool's) is still declared on its first message, with that cost. A client that subscribes to a topic whose
messages are rare (the header, the arm, the cell, the mugs, the plan, the last state) gets the latest message
at once instead of waiting for the next; the SDK cannot send to one client alone, so clients already
subscribed to that topic get it again.

The operator's verbs are offered as Foxglove services (``offer_commands``), named like their Zenoh keys
(``dishbot/<robot_id>/cmd/<verb>``), JSON in and out, handled by the same function as the Zenoh commands.
Only on a loopback address: the server has no authentication, and off loopback anyone who reaches the port
could command the arm (it then says so in a log line and offers none).

The server speaks Foxglove's WebSocket protocol as the SDK does (subprotocol ``foxglove.sdk.v1``); a client
asking only for the older ``foxglove.websocket.v1`` is refused during the handshake (HTTP 400). It listens on
loopback unless the config says ``insecure = true`` (``config.check_foxglove_listen``).
"""

from __future__ import annotations

import asyncio
import json
import threading
from collections.abc import Callable, Coroutine, Iterable, Sequence
from typing import Any, Final

import foxglove
import structlog
from foxglove.websocket import (
    Capability,
    ChannelView,
    Client,
    MessageSchema,
    ServerListener,
    Service,
    ServiceRequest,
    ServiceSchema,
    WebSocketServer,
)

from recorder.errors import LiveServerError
from recorder.foxglove_scene import ARM, CALIBRATION, CELL, DEPTH, MUGS, PLAN, STATUS, TF, TOPICS, channel
from recorder.writer import ChannelSpec, json_channel
from validation.hosts import is_loopback
from wire.schemas import HEADER_TOPIC, described_topics, topic_suffix

log = structlog.get_logger(__name__)

SUBPROTOCOL: Final = "foxglove.sdk.v1"
# Topics whose latest message a new subscriber gets at once.
_LATCHED: Final = frozenset({HEADER_TOPIC, ARM, CELL, MUGS, PLAN, STATUS, CALIBRATION, DEPTH, TF})
_LATCHED_JSON: Final = frozenset({"state", "plan", "detections"})
# Messages the SDK keeps per client while the client reads slower than the robot writes (a simulated job
# at full speed writes thousands a second); beyond it the oldest are dropped for that client.
BACKLOG: Final = 65_536
# How long a service call may wait for the daemon's answer (a command is answered at once; a loop gone
# answers never).
_COMMAND_TIMEOUT_S: Final = 10.0

# A command as the daemon handles it: (verb, payload, addressed to many robots) -> the reply.
CommandHandler = Callable[[str, bytes, bool], Coroutine[Any, Any, dict[str, object]]]


def known_channels(robot_id: str, *, scene: bool) -> list[ChannelSpec]:
    """Every channel the daemon of ``robot_id`` can record: the header, the JSON channel of each described
    topic and (``scene``: Foxglove channels on) the Foxglove scene's."""
    specs = [json_channel(HEADER_TOPIC)]
    specs += [json_channel(f"dishbot/{robot_id}/{suffix}") for suffix in described_topics()]
    if scene:
        specs += [channel(topic) for topic in TOPICS]
    return specs


class LiveServer(ServerListener):
    """A Foxglove WebSocket server on ``host:port`` serving what the recorder sends it, with ``channels``
    declared from the start."""

    def __init__(
        self,
        host: str,
        port: int,
        *,
        name: str,
        channels: Iterable[ChannelSpec] = (),
        backlog: int = BACKLOG,
    ) -> None:
        self._context = foxglove.Context()
        self._lock = threading.Lock()
        self._channels: dict[str, foxglove.Channel] = {}
        self._latest: dict[str, tuple[bytes, int]] = {}
        self.commands_allowed = is_loopback(host)
        for spec in channels:  # before the server exists: its first client sees them all at once
            self._declare(spec)
        try:
            self._server: WebSocketServer = foxglove.start_server(
                name=name,
                host=host,
                port=port,
                context=self._context,
                server_listener=self,
                capabilities=[Capability.Services] if self.commands_allowed else [],
                supported_encodings=["json"],
                message_backlog_size=backlog,
            )
        except RuntimeError as e:
            reason = str(e).removeprefix("FoxgloveError: ")
            raise LiveServerError(f"cannot start the Foxglove server on {host}:{port}: {reason}") from e
        self.host = host
        self.port = self._server.port
        log.info("foxglove_server_started", host=host, port=self.port, channels=len(self._channels))

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"ws://{host}:{self.port}"

    def offer_commands(
        self,
        loop: asyncio.AbstractEventLoop,
        handle: CommandHandler,
        robot_id: str,
        verbs: Sequence[str],
        *,
        max_payload_bytes: int,
    ) -> list[str]:
        """Offer each verb as the service ``dishbot/<robot_id>/cmd/<verb>``, answered by ``handle`` on
        ``loop`` (the daemon's own command path: same validation, same recording) after the same size check
        as a Zenoh query; the reply is the Zenoh reply's JSON. Returns the names offered (none off loopback,
        said in a log line)."""
        if not self.commands_allowed:
            log.warning(
                "foxglove_commands_not_offered",
                host=self.host,
                reason="the server is not on loopback and has no authentication: command over Zenoh",
            )
            return []
        services = [
            self._service(loop, handle, robot_id, verb, max_payload_bytes=max_payload_bytes) for verb in verbs
        ]
        self._server.add_services(services)
        names = [s.name for s in services]
        log.info("foxglove_commands_offered", services=names)
        return names

    def declared(self) -> frozenset[str]:
        """The topics whose channels exist (and are advertised to every client that connects from now)."""
        with self._lock:
            return frozenset(self._channels)

    def send(self, channel: ChannelSpec, data: bytes, log_time_ns: int) -> None:
        """Log one message to the connected clients (called on the recorder's thread)."""
        with self._lock:
            live = self._channels.get(channel.topic) or self._declare(channel)
            if channel.topic in _LATCHED or topic_suffix(channel.topic) in _LATCHED_JSON:
                self._latest[channel.topic] = (data, log_time_ns)
        live.log(data, log_time=log_time_ns)

    def close(self) -> None:
        self._server.stop()
        with self._lock:
            for live in self._channels.values():
                live.close()
            self._channels.clear()
        log.info("foxglove_server_stopped", port=self.port)

    def _declare(self, spec: ChannelSpec) -> foxglove.Channel:
        live = self._channels[spec.topic] = foxglove.Channel(
            spec.topic,
            schema=foxglove.Schema(
                name=spec.schema_name, encoding=spec.schema_encoding, data=spec.schema_data
            ),
            message_encoding=spec.message_encoding,
            context=self._context,
        )
        return live

    def _service(
        self,
        loop: asyncio.AbstractEventLoop,
        handle: CommandHandler,
        robot_id: str,
        verb: str,
        *,
        max_payload_bytes: int,
    ) -> Service:
        def call(request: ServiceRequest) -> bytes:  # on a thread of the server's, never the loop
            return json.dumps({"robot_id": robot_id, **answer(request.payload)}).encode()

        def answer(payload: bytes) -> dict[str, object]:
            if len(payload) > max_payload_bytes:
                return {
                    "ok": False,
                    "error": f"payload of {len(payload)} bytes is larger than the limit of "
                    f"{max_payload_bytes} bytes",
                }
            try:
                reply = asyncio.run_coroutine_threadsafe(handle(verb, payload, False), loop)
            except RuntimeError:  # the loop is closed
                return {"ok": False, "error": "the daemon is shutting down"}
            try:
                return reply.result(timeout=_COMMAND_TIMEOUT_S)
            except TimeoutError:
                reply.cancel()
                return {"ok": False, "error": f"no answer within {_COMMAND_TIMEOUT_S:g} s"}
            except Exception as e:  # the caller must get an answer whatever went wrong
                log.exception("command_crashed", verb=verb, via="foxglove")
                return {"ok": False, "error": f"internal error handling {verb}: {e!r}"}

        schema = ServiceSchema(
            f"dishbot.cmd.{verb}",
            request=_json_schema(f"dishbot.cmd_{verb}", _REQUEST_SCHEMA[verb == "start"]),
            response=_json_schema("dishbot.cmd_reply", _REPLY_SCHEMA),
        )
        return Service(f"dishbot/{robot_id}/cmd/{verb}", schema=schema, handler=call)

    # --- called by the server's threads ----------------------------------------------------------------

    def on_subscribe(self, client: Client, channel: ChannelView) -> None:
        with self._lock:
            latest = self._latest.get(channel.topic)
            live = self._channels.get(channel.topic)
        if latest is not None and live is not None:
            live.log(latest[0], log_time=latest[1])


_START_REQUEST: Final = json.dumps(
    {
        "type": "object",
        "description": "start a job: a dataset or the mugs on the counter, and planner settings (README)",
        "properties": {
            "dataset": {"type": "integer", "minimum": 1},
            "mugs": {"type": "array", "items": {"type": "object"}},
            "planner": {"type": "object"},
        },
        "additionalProperties": False,
    }
).encode()
_EMPTY_REQUEST: Final = json.dumps(
    {"type": "object", "description": "no arguments: {}", "additionalProperties": False}
).encode()
_REQUEST_SCHEMA: Final = {True: _START_REQUEST, False: _EMPTY_REQUEST}
_REPLY_SCHEMA: Final = json.dumps(
    {
        "type": "object",
        "description": "the daemon's reply, as over Zenoh: ok, and the error when refused",
        "properties": {"ok": {"type": "boolean"}, "error": {"type": "string"}},
        "required": ["ok"],
    }
).encode()


def _json_schema(name: str, data: bytes) -> MessageSchema:
    return MessageSchema(encoding="json", schema=foxglove.Schema(name=name, encoding="jsonschema", data=data))
