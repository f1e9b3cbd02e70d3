"""The client side of Foxglove's WebSocket protocol (``foxglove.sdk.v1``), as the Foxglove app speaks it: JSON
control messages (serverInfo, advertise, advertiseServices, status, subscribe), binary message data and
service calls. Written from the protocol's specification, for the tests of the live server."""

from __future__ import annotations

import asyncio
import base64
import collections
import contextlib
import json
import struct
import time
from dataclasses import dataclass, field
from typing import Any

import websockets
from websockets.typing import Subprotocol

from tests.recorder.foxglove_decode import message_class

SUBPROTOCOL = "foxglove.sdk.v1"
_MESSAGE_DATA = 1  # server -> client binary opcodes
_SERVICE_CALL_RESPONSE = 3
_SERVICE_CALL_REQUEST = 2  # client -> server


@dataclass(frozen=True, slots=True)
class Received:
    topic: str
    log_time_ns: int
    data: bytes


@dataclass
class FoxgloveClient:
    """One connection: what the server advertised and sent, and ways to subscribe and call services."""

    ws: Any
    channels: dict[int, dict[str, Any]] = field(default_factory=dict)
    services: dict[str, dict[str, Any]] = field(default_factory=dict)
    subscriptions: dict[int, int] = field(default_factory=dict)
    server_info: dict[str, Any] = field(default_factory=dict)
    statuses: list[dict[str, Any]] = field(default_factory=list)
    received: list[Received] = field(default_factory=list)
    counts: collections.Counter[str] = field(default_factory=collections.Counter)  # received, by topic
    replies: dict[int, tuple[str, bytes]] = field(default_factory=dict)
    failures: dict[int, str] = field(default_factory=dict)
    _next_call: int = 1

    @classmethod
    async def connect(cls, url: str) -> FoxgloveClient:
        ws = await websockets.connect(url, subprotocols=[Subprotocol(SUBPROTOCOL)], max_size=None)
        assert ws.subprotocol == SUBPROTOCOL
        return cls(ws)

    async def close(self) -> None:
        """The closing handshake, reading (and dropping) what the server still sends meanwhile: websockets
        stops reading the socket while its queue of unread messages is full, so a server that goes on
        sending would hold its close frame back until websockets gives up after 10 s."""
        drain = asyncio.create_task(self._drop_until_closed())
        await self.ws.close()
        await drain

    async def _drop_until_closed(self) -> None:
        with contextlib.suppress(websockets.ConnectionClosed):
            while True:
                await self.ws.recv()

    def topics(self) -> set[str]:
        return {c["topic"] for c in self.channels.values()}

    async def advertised(self, topics: set[str], timeout_s: float = 10.0) -> None:
        deadline = time.monotonic() + timeout_s
        while not topics <= self.topics():
            await self.receive(deadline)

    async def subscribe(self, topics: list[str]) -> None:
        by_topic = {c["topic"]: cid for cid, c in self.channels.items()}
        subs = [{"id": i, "channelId": by_topic[t]} for i, t in enumerate(topics)]
        self.subscriptions = {s["id"]: s["channelId"] for s in subs}
        await self.ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))

    async def messages(self, count: int, timeout_s: float = 10.0) -> list[Received]:
        start = len(self.received)
        deadline = time.monotonic() + timeout_s
        while len(self.received) - start < count:
            await self.receive(deadline)
        return self.received[start:]

    async def until(self, topic: str, predicate: Any, timeout_s: float = 60.0) -> Received:
        """Receive until a message on ``topic`` satisfies ``predicate(message)``; that message."""
        start = len(self.received)
        deadline = time.monotonic() + timeout_s
        while True:
            for m in self.received[start:]:
                if m.topic == topic and predicate(m):
                    return m
            start = len(self.received)
            await self.receive(deadline)

    async def call(self, service: str, payload: dict[str, Any], timeout_s: float = 30.0) -> dict[str, Any]:
        """Call a service with a JSON request; its JSON reply (AssertionError on a call failure)."""
        return await self.call_raw(service, json.dumps(payload).encode(), timeout_s)

    async def call_raw(self, service: str, body: bytes, timeout_s: float = 30.0) -> dict[str, Any]:
        """Call a service with ``body`` as the request, whatever it holds; its JSON reply."""
        call_id = self._next_call
        self._next_call += 1
        service_id = self.services[service]["id"]
        encoding = b"json"
        header = struct.pack("<BIII", _SERVICE_CALL_REQUEST, service_id, call_id, len(encoding))
        await self.ws.send(header + encoding + body)
        deadline = time.monotonic() + timeout_s
        while call_id not in self.replies:
            assert call_id not in self.failures, self.failures[call_id]
            await self.receive(deadline)
        encoding_text, data = self.replies[call_id]
        assert encoding_text == "json"
        reply: dict[str, Any] = json.loads(data)
        return reply

    async def receive(self, deadline: float) -> None:
        frame = await asyncio.wait_for(self.ws.recv(), max(0.01, deadline - time.monotonic()))
        if isinstance(frame, str):
            doc = json.loads(frame)
            op = doc["op"]
            if op == "serverInfo":
                self.server_info = doc
            elif op == "advertise":
                self.channels.update({c["id"]: c for c in doc["channels"]})
            elif op == "unadvertise":
                for cid in doc["channelIds"]:
                    self.channels.pop(cid, None)
            elif op == "advertiseServices":
                self.services.update({s["name"]: s for s in doc["services"]})
            elif op == "status":
                self.statuses.append(doc)
            elif op == "serviceCallFailure":
                self.failures[doc["callId"]] = doc["message"]
            return
        opcode = frame[0]
        if opcode == _MESSAGE_DATA:
            sub_id, log_time = struct.unpack_from("<IQ", frame, 1)
            topic = self.channels[self.subscriptions[sub_id]]["topic"]
            self.received.append(Received(topic, log_time, bytes(frame[13:])))
            self.counts[topic] += 1
        elif opcode == _SERVICE_CALL_RESPONSE:
            _, call_id, length = struct.unpack_from("<III", frame, 1)
            encoding = bytes(frame[13 : 13 + length]).decode()
            self.replies[call_id] = (encoding, bytes(frame[13 + length :]))

    def decode(self, topic: str, data: bytes) -> Any:
        channel = next(c for c in self.channels.values() if c["topic"] == topic)
        if channel["encoding"] == "json":
            return json.loads(data)
        assert (channel["encoding"], channel["schemaEncoding"]) == ("protobuf", "protobuf")
        return message_class(channel["schemaName"], base64.b64decode(channel["schema"])).FromString(data)
