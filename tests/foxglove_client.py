"""A Foxglove WebSocket client, as Foxglove's app connects to a live view: it takes the
advertised channels, subscribes to all of them and collects what arrives (protocol
``foxglove.sdk.v1``: JSON control messages, binary message data).

It subscribes once to each channel, as a viewer does, and does not ask again when the
server refuses ("Unknown channel ID: N", the SDK's race: docs/telemetry.md); the live
view must then advertise that channel again, which this client subscribes to as to any
new one. The refusals stay in ``statuses`` for a failure message."""

from __future__ import annotations

import json
import struct
import time
from collections import defaultdict
from dataclasses import dataclass, field
from typing import Any

from websockets.exceptions import ConnectionClosed
from websockets.sync.client import connect

SUBPROTOCOL = "foxglove.sdk.v1"  # the SDK server refuses the older foxglove.websocket.v1
MESSAGE_DATA = 0x01


@dataclass
class Received:
    channels: dict[int, dict[str, Any]] = field(default_factory=dict)  # id -> advertisement
    # (channels unadvertised since are dropped)
    messages: dict[str, list[tuple[int, bytes]]] = field(
        default_factory=lambda: defaultdict(list))  # topic -> (log time ns, payload)
    server_info: dict[str, Any] | None = None
    statuses: list[dict[str, Any]] = field(default_factory=list)  # the server's status ops
    ended: str = ""  # why collecting stopped: time, closed (with the code), until

    def topics(self) -> set[str]:
        return {c["topic"] for c in self.channels.values()}

    def summary(self) -> str:
        """What arrived, for a failure message: messages per topic, the server's statuses,
        why collecting ended (a lost live-view stream is traced from here)."""
        counts = {topic: len(m) for topic, m in self.messages.items()}
        return (f"ended: {self.ended}; messages per topic: {counts}; advertised: "
                f"{sorted(self.topics())}; statuses: {self.statuses[:5]}")


def connect_when_up(url: str, timeout_s: float = 30.0):
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            # close_timeout: the SDK's server stops reading at a viewer's close frame and
            # does not always answer it (the default waits 10 s for the answer).
            return connect(url, subprotocols=[SUBPROTOCOL], open_timeout=2.0,
                           close_timeout=1.0)
        except OSError:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.05)


def collect(url: str, seconds: float, until: Any = None,
            timeout_s: float = 30.0) -> Received:
    """Subscribe once to every channel advertised (now or later) and collect for
    ``seconds`` of wall time, or until ``until(received)`` is true, or the server
    closes."""
    got = Received()
    subscription_topic: dict[int, str] = {}

    def subscribe(channel_ids: list[int]) -> None:
        subscriptions = []
        for channel_id in channel_ids:
            sub_id = len(subscription_topic) + 1
            subscription_topic[sub_id] = got.channels[channel_id]["topic"]
            subscriptions.append({"id": sub_id, "channelId": channel_id})
        ws.send(json.dumps({"op": "subscribe", "subscriptions": subscriptions}))

    with connect_when_up(url, timeout_s) as ws:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            try:
                frame = ws.recv(timeout=max(0.01, end - time.monotonic()))
            except TimeoutError:
                got.ended = "time"
                break
            except ConnectionClosed as exc:
                got.ended = f"closed ({exc})"
                break
            if isinstance(frame, str):
                message = json.loads(frame)
                if message["op"] == "serverInfo":
                    got.server_info = message
                elif message["op"] == "status":
                    got.statuses.append(message)
                elif message["op"] == "unadvertise":
                    for channel_id in message["channelIds"]:
                        got.channels.pop(channel_id, None)
                elif message["op"] == "advertise":
                    for channel in message["channels"]:
                        got.channels[channel["id"]] = channel
                    subscribe([channel["id"] for channel in message["channels"]])
            elif frame and frame[0] == MESSAGE_DATA:
                sub_id, log_time_ns = struct.unpack_from("<IQ", frame, 1)
                got.messages[subscription_topic[sub_id]].append((log_time_ns, frame[13:]))
            if until is not None and until(got):
                got.ended = "until"
                break
        else:
            got.ended = got.ended or "time"
    return got
