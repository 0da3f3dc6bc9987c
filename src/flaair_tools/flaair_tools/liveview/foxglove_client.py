"""A minimal Foxglove WebSocket protocol client (the
`websockets` package), for tests and benchmarks.

Protocol (https://github.com/foxglove/ws-protocol): the client offers the subprotocol
(``foxglove.websocket.v1``, or ``foxglove.sdk.v1`` which foxglove-sdk 0.30 servers speak);
the server sends ``serverInfo`` and ``advertise`` (JSON text frames); the client sends
``subscribe`` with its own subscription ids; the server then sends binary frames: opcode 1
MessageData (uint32 subscription id, uint64 log time ns, payload) and opcode 2 Time (uint64 ns).
"""

from __future__ import annotations

import json
import struct
from dataclasses import dataclass, field

from websockets.sync.client import ClientConnection, connect

SUBPROTOCOLS = ["foxglove.websocket.v1", "foxglove.sdk.v1"]
MESSAGE_DATA, TIME = 1, 2


@dataclass
class Received:
    """What a client has received, per topic: (log time ns, payload) in arrival order."""

    messages: dict[str, list[tuple[int, bytes]]] = field(default_factory=dict)
    times_ns: list[int] = field(default_factory=list)

    def count(self) -> int:
        return sum(len(items) for items in self.messages.values())


class FoxgloveClient:
    """Connect, learn the channels, subscribe to topics, receive until told to stop."""

    def __init__(self, url: str, open_timeout_s: float = 10.0) -> None:
        self.connection: ClientConnection = connect(
            url, subprotocols=SUBPROTOCOLS, open_timeout=open_timeout_s, max_size=None, legacy=True
        )
        self.channels: dict[str, dict] = {}
        self.by_subscription: dict[int, str] = {}
        self.received = Received()

    def wait_for_channels(self, topics: list[str], timeout_s: float) -> None:
        """Read control frames until every topic in `topics` is advertised (TimeoutError if not)."""
        while not all(topic in self.channels for topic in topics):
            self._handle(self.connection.recv(timeout=timeout_s))

    def subscribe(self, topics: list[str]) -> None:
        """Subscribe to advertised topics (subscription id = position + 1)."""
        subscriptions = []
        for number, topic in enumerate(topics, start=1):
            subscriptions.append({"id": number, "channelId": self.channels[topic]["id"]})
            self.by_subscription[number] = topic
            self.received.messages.setdefault(topic, [])
        self.connection.send(json.dumps({"op": "subscribe", "subscriptions": subscriptions}))

    def receive(self, timeout_s: float) -> bool:
        """Handle one frame; False when none arrived within `timeout_s`."""
        try:
            frame = self.connection.recv(timeout=timeout_s)
        except TimeoutError:
            return False
        self._handle(frame)
        return True

    def _handle(self, frame: str | bytes) -> None:
        if isinstance(frame, str):
            message = json.loads(frame)
            if message.get("op") == "advertise":
                self.channels.update({channel["topic"]: channel for channel in message["channels"]})
            return
        if frame[0] == MESSAGE_DATA:
            subscription, log_time_ns = struct.unpack_from("<IQ", frame, 1)
            self.received.messages[self.by_subscription[subscription]].append(
                (log_time_ns, bytes(frame[13:]))
            )
        elif frame[0] == TIME:
            self.received.times_ns.append(struct.unpack_from("<Q", frame, 1)[0])

    def close(self) -> None:
        self.connection.close()
