"""The live Foxglove view: the Foxglove SDK's WebSocket server, fed with every channel the recorder writes.

The server is a ``recording.writer.Tee``: the recorder's thread hands it each message it handles (the JSON
channels and the Foxglove channels derived from them), so the live view and the recording show the same
channels, the live one at the full rate even while idle files are thinned. Channels are advertised as their
first message arrives. A client that subscribes to a topic whose messages are rare (the arm, the cell, the
mugs, the plan, the last state) gets the latest message at once instead of waiting for the next.

The server speaks Foxglove's WebSocket protocol (subprotocol ``foxglove.sdk.v1``). It has no authentication,
so it listens on loopback unless the config says ``insecure = true`` (``config.check_foxglove_listen``).
"""

from __future__ import annotations

import threading
from typing import Final

import foxglove
import structlog
from foxglove.websocket import ChannelView, Client, ServerListener, WebSocketServer

from recorder.errors import LiveServerError
from recorder.foxglove_scene import ARM, CALIBRATION, CELL, DEPTH, MUGS, PLAN, STATUS, TF
from recorder.writer import ChannelSpec
from wire.schemas import HEADER_TOPIC, topic_suffix

log = structlog.get_logger(__name__)

# Topics whose latest message a new subscriber gets at once.
_LATCHED: Final = frozenset({ARM, CELL, MUGS, PLAN, STATUS, CALIBRATION, DEPTH, TF})
_LATCHED_JSON: Final = frozenset({"state", "plan", "detections"})


class LiveServer(ServerListener):
    """A Foxglove WebSocket server on ``host:port`` serving what the recorder sends it."""

    def __init__(self, host: str, port: int, *, name: str) -> None:
        self._context = foxglove.Context()
        self._lock = threading.Lock()
        self._channels: dict[str, foxglove.Channel] = {}
        self._latest: dict[str, tuple[bytes, int]] = {}
        try:
            self._server: WebSocketServer = foxglove.start_server(
                name=name, host=host, port=port, context=self._context, server_listener=self
            )
        except RuntimeError as e:
            reason = str(e).removeprefix("FoxgloveError: ")
            raise LiveServerError(f"cannot start the Foxglove server on {host}:{port}: {reason}") from e
        self.host = host
        self.port = self._server.port
        log.info("foxglove_server_started", host=host, port=self.port)

    @property
    def url(self) -> str:
        return f"ws://{self.host}:{self.port}"

    def send(self, channel: ChannelSpec, data: bytes, log_time_ns: int) -> None:
        """Log one message to the connected clients (called on the recorder's thread)."""
        if channel.topic == HEADER_TOPIC:
            return
        with self._lock:
            live = self._channels.get(channel.topic)
            if live is None:
                live = self._channels[channel.topic] = foxglove.Channel(
                    channel.topic,
                    schema=foxglove.Schema(
                        name=channel.schema_name, encoding=channel.schema_encoding, data=channel.schema_data
                    ),
                    message_encoding=channel.message_encoding,
                    context=self._context,
                )
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

    # --- called by the server's threads ----------------------------------------------------------------

    def on_subscribe(self, client: Client, channel: ChannelView) -> None:
        with self._lock:
            latest = self._latest.get(channel.topic)
            live = self._channels.get(channel.topic)
        if latest is not None and live is not None:
            live.log(latest[0], log_time=latest[1])
