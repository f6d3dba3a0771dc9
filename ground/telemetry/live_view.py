"""The live view: the flight in Foxglove while it flies, over Foxglove's WebSocket protocol
(docs/telemetry.md#foxglove).

``LiveView`` is a WebSocket server (the ``foxglove-sdk`` package) that publishes what
``ground/telemetry/foxglove_view.py`` makes of the telemetry. It is fed by the logger
(``ivfm ground log --view``, ``ivfm run --view``: one conversion serves the file and the
viewer) or by a Zenoh session of its own (``ivfm ground view``).

Bounded by construction: the server keeps at most ``backlog`` messages per viewer and
drops the oldest when a viewer is slow; ``ivfm ground view``'s inbox holds at most
``MAX_INBOX`` puts and ``MAX_INBOX_BYTES`` of payload, drops new ones past either
(counted), and gives a drained backlog's memory back (``ground/telemetry/inbox.py``).
Nothing here waits for a viewer, so a slow or absent one costs the logger only the
conversion, and the vehicles nothing.

A channel is created with its topic's first message, often while a viewer is connected;
the SDK (foxglove-sdk 0.30) then refuses, now and then, the viewer's subscription to it
("Unknown channel ID: N"), and a viewer subscribes once. ``LiveView`` hears the refusal
in the SDK's log and advertises that channel again under a new id, which the viewer
subscribes to (docs/telemetry.md, "A subscription refused").
"""

from __future__ import annotations

import argparse
import collections
import json
import logging
import re
import sys
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

import foxglove
import zenoh
from foxglove import channels as fg_channels

from contracts.arguments import number
from contracts.stop_request import StopRequest
from contracts.telemetry import unbatched
from contracts.zenoh_link import ZenohOptions, open_session
from ground.telemetry.foxglove_scene import JsonText, channel_json_schema, encode
from ground.telemetry.foxglove_view import DEFAULT_RATE_HZ, FoxgloveView, Output
from ground.telemetry.inbox import Inbox

DEFAULT_VIEW_PORT = 8765
# Foxglove's layout for these topics (3D, tracking, motors, adaptation, estimator, log):
# in Foxglove, Layouts, Import from file.
LAYOUT_FILE = Path(__file__).parent / "layouts" / "ivfm-sitl.foxglove-layout.json"
MAX_INBOX = 50_000  # puts (a batch is one)
MAX_INBOX_BYTES = 32 * 1024 * 1024  # their payloads
SUBSCRIBED = ("ivfm/vehicle/**", "mavlink/**")
# Where foxglove-sdk logs a subscription it refused (its Rust target, through Python's
# logging), and how: the only report of one the SDK gives its host.
SDK_CLIENT_LOGGER = "foxglove.websocket.connected_client"
REFUSED = re.compile(r"subscribe to unknown channel: (\d+)$")
# Advertisements again per topic, at most: a refusal is the SDK's race, met at most 11
# times in a row for one topic even by a publishing thread that always loses the CPU
# (tests/ground/test_live_view.py); 50 in a row is a viewer asking for channel ids
# before they exist.
MAX_READVERTISED = 50


def view_address(text: str) -> tuple[str, int]:
    """argparse type of ``--view``: ``PORT`` or ``HOST:PORT`` (host: loopback by default;
    port 0: any free one, said at start)."""
    host, _, port = text.rpartition(":")
    try:
        number = int(port)
    except ValueError:
        number = -1
    if not 0 <= number <= 65535 or (host and not all(c.isalnum() or c in ".-[]:"
                                                        for c in host)):
        raise argparse.ArgumentTypeError(
            f"must be PORT or HOST:PORT with a port in [0, 65535], got {text!r}")
    return host.strip("[]") or "127.0.0.1", number


def add_view_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--view-rate-hz", type=number(1, 1000, "Hz"), default=DEFAULT_RATE_HZ,
                        help="what Foxglove draws, at most this often in sim time "
                             f"(default {DEFAULT_RATE_HZ:g} Hz; the path at 2 Hz)")


class _Refusals(logging.Handler):
    """The ids of the channels whose subscription the SDK refused, read from its log.
    This runs on the server's thread, inside the SDK's locks: it only takes note, and
    the publishing thread acts (``LiveView._advertise_again``)."""

    def __init__(self) -> None:
        super().__init__(logging.ERROR)
        self.ids: collections.deque[int] = collections.deque(maxlen=1024)

    def emit(self, record: logging.LogRecord) -> None:
        refused = REFUSED.search(record.getMessage())
        if refused:
            self.ids.append(int(refused.group(1)))


class LiveView:
    """A Foxglove WebSocket server; ``publish`` sends one converted message to every
    viewer subscribed to its topic (none subscribed: the SDK sends nothing). One thread
    publishes."""

    def __init__(self, host: str = "127.0.0.1", port: int = DEFAULT_VIEW_PORT,
                 backlog: int = 1024, log: Callable[[str], None] | None = None) -> None:
        self.log = log or (lambda text: print(f"live view: {text}", file=sys.stderr,
                                              flush=True))
        self.context = foxglove.Context()
        self._refusals = _Refusals()
        sdk_log = logging.getLogger(SDK_CLIENT_LOGGER)
        if sdk_log.getEffectiveLevel() > logging.ERROR:  # the SDK logs a refusal as an error
            sdk_log.setLevel(logging.ERROR)
        sdk_log.addHandler(self._refusals)
        try:
            self.server = foxglove.start_server(name="ivfm-sitl", host=host, port=port,
                                                context=self.context,
                                                message_backlog_size=backlog)
        except RuntimeError as exc:  # the SDK's error for a port in use, a bad host
            sdk_log.removeHandler(self._refusals)
            raise OSError(f"cannot serve the live view on {host}:{port}: {exc}") from None
        self.host = host
        self.channels: dict[str, Any] = {}  # topic -> the SDK's channel
        self._makers: dict[str, Callable[[], Any]] = {}  # topic -> makes its channel
        self._topics: dict[int, str] = {}  # channel id -> topic, for this server's channels
        self.advertised_again: collections.Counter[str] = collections.Counter()
        self.published = 0

    @property
    def port(self) -> int:
        return self.server.port

    @property
    def url(self) -> str:
        return f"ws://{self.host}:{self.port}"

    def publish(self, output: Output) -> None:
        if self._refusals.ids:
            self._advertise_again()
        channel = self.channels.get(output.topic)
        if channel is None:
            channel = self._add(output.topic, self._maker(output))
        # Logged whether or not a viewer is subscribed (the SDK sends nothing then).
        message = output.message
        channel.log(encode(message) if isinstance(message, dict | JsonText) else message,
                    log_time=output.sim_time_ns)
        self.published += 1

    def _maker(self, output: Output) -> Callable[[], Any]:
        """What makes the channel of ``output``'s topic (its schema from this first
        message), kept to make it again."""
        message, topic, context = output.message, output.topic, self.context
        fields = channel_json_schema(message)
        if fields is not None:
            schema = foxglove.Schema(name=f"ivfm.view{topic.replace('/', '.')}",
                                     encoding="jsonschema", data=json.dumps(fields).encode())
            return lambda: foxglove.Channel(topic, message_encoding="json", schema=schema,
                                            context=context)
        typed = getattr(fg_channels, f"{type(message).__name__}Channel")
        return lambda: typed(topic, context=context)

    def _add(self, topic: str, make: Callable[[], Any]) -> Any:
        channel = self.channels[topic] = make()  # advertised to every viewer connected
        self._makers[topic] = make
        self._topics[channel.id()] = topic
        return channel

    def _advertise_again(self) -> None:
        """Each channel whose subscription the SDK refused: closed (unadvertised) and
        made again under a new id, which the viewer subscribes to. The SDK sends a
        channel's advertisement before it records the channel for the viewer, and
        refuses a subscription that comes in between; its thread then records it, but
        the viewer, refused, does not ask again (docs/telemetry.md)."""
        while self._refusals.ids:
            topic = self._topics.pop(self._refusals.ids.popleft(), None)
            if topic is None or self.advertised_again[topic] >= MAX_READVERTISED:
                continue  # another server's channel, one advertised again, or past the cap
            self.advertised_again[topic] += 1
            # Closed first: the SDK would hand back an equal open channel, same id.
            self.channels.pop(topic).close()
            self._add(topic, self._makers[topic])
            self.log(f"advertised {topic} again: a viewer's subscription to it was refused "
                     f"by the SDK ({self.advertised_again[topic]} for this topic)")

    def close(self) -> None:
        self.server.stop()
        logging.getLogger(SDK_CLIENT_LOGGER).removeHandler(self._refusals)


def serve_view(options: ZenohOptions, host: str, port: int, rate_hz: float = DEFAULT_RATE_HZ,
               stop: StopRequest | None = None,
               ready: Callable[[LiveView], None] | None = None,
               log: Callable[[str], None] | None = None) -> int:
    """``ivfm ground view``: the telemetry heard on ``options``' session, live, until
    ``stop`` (or SIGINT / SIGTERM)."""
    log = log or (lambda text: print(f"view: {text}", file=sys.stderr, flush=True))
    stop = stop or StopRequest()
    if threading.current_thread() is threading.main_thread():
        stop.on_signals()
    view = FoxgloveView(rate_hz)
    live = LiveView(host, port, log=log)
    inbox = Inbox(MAX_INBOX, MAX_INBOX_BYTES)  # (key, payload, attachment)
    dropped = refused = 0

    def on_sample(sample: zenoh.Sample) -> None:
        nonlocal dropped
        attachment = sample.attachment
        size_bytes = len(sample.payload) + (len(attachment) if attachment is not None else 0)
        if not inbox.put((str(sample.key_expr), sample.payload.to_bytes(),
                          attachment.to_bytes() if attachment is not None else None),
                         size_bytes):
            dropped += 1

    def draw(key: str, payload: bytes, attachment: bytes | None) -> None:
        nonlocal refused
        try:
            outputs = [out for record in unbatched(key, payload, attachment)
                       for out in view.feed(*record)]
        except (ValueError, TypeError, KeyError) as exc:
            refused += 1
            if refused == 1 or refused % 1000 == 0:
                log(f"cannot draw a record on {key}: {exc} ({refused} so far)")
            return
        for output in outputs:
            live.publish(output)

    session = open_session(options)
    subscribers = [session.declare_subscriber(k, on_sample) for k in SUBSCRIBED]
    log(f"serving the live view on {live.url} (Foxglove: open connection, Foxglove "
        "WebSocket); telemetry from "
        f"{', '.join(options.connect or options.listen) or 'this machine'}; layout "
        f"{LAYOUT_FILE}")
    if ready is not None:
        ready(live)
    try:
        while not stop.is_set():
            if not inbox:
                stop.wait(0.005)
                continue
            inbox.drain(draw)
    finally:
        for sub in subscribers:
            sub.undeclare()
        session.close()
        live.close()
        log(f"stopped: {live.published} messages offered to viewers, {dropped} records "
            f"dropped (inbox full), {refused} not drawn")
    return 0
