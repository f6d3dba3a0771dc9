"""The live view: the flight in Foxglove while it flies, over Foxglove's WebSocket protocol
(docs/telemetry.md#foxglove).

``LiveView`` is a WebSocket server (the ``foxglove-sdk`` package) that publishes what
``ground/telemetry/foxglove_view.py`` makes of the telemetry. It is fed by the logger
(``ivfm ground log --view``, ``ivfm run --view``: one conversion serves the file and the
viewer) or by a Zenoh session of its own (``ivfm ground view``).

Bounded by construction: the server keeps at most ``backlog`` messages per viewer and
drops the oldest when a viewer is slow; ``ivfm ground view``'s inbox holds at most
``MAX_INBOX`` records and drops new ones past it (counted). Nothing here waits for a
viewer, so a slow or absent one costs the logger only the conversion, and the vehicles
nothing.
"""

from __future__ import annotations

import argparse
import collections
import json
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
from ground.telemetry.foxglove_scene import encode, json_schema
from ground.telemetry.foxglove_view import DEFAULT_RATE_HZ, FoxgloveView, Output

DEFAULT_VIEW_PORT = 8765
# Foxglove's layout for these topics (3D, tracking, motors, adaptation, estimator, log):
# in Foxglove, Layouts, Import from file.
LAYOUT_FILE = Path(__file__).parent / "layouts" / "ivfm-sitl.foxglove-layout.json"
MAX_INBOX = 50_000
SUBSCRIBED = ("ivfm/vehicle/**", "mavlink/**")


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


class LiveView:
    """A Foxglove WebSocket server; ``publish`` sends one converted message to every
    viewer subscribed to its topic (none subscribed: the SDK sends nothing)."""

    def __init__(self, host: str = "127.0.0.1", port: int = DEFAULT_VIEW_PORT,
                 backlog: int = 1024) -> None:
        self.context = foxglove.Context()
        try:
            self.server = foxglove.start_server(name="ivfm-sitl", host=host, port=port,
                                                context=self.context,
                                                message_backlog_size=backlog)
        except RuntimeError as exc:  # the SDK's error for a port in use, a bad host
            raise OSError(f"cannot serve the live view on {host}:{port}: {exc}") from None
        self.host = host
        self.channels: dict[str, Any] = {}
        self.published = 0

    @property
    def port(self) -> int:
        return self.server.port

    @property
    def url(self) -> str:
        return f"ws://{self.host}:{self.port}"

    def publish(self, output: Output) -> None:
        channel = self.channels.get(output.topic)
        if channel is None:
            channel = self.channels[output.topic] = self._channel(output)
        # Logged whether or not a viewer is subscribed (the SDK sends nothing then). Not
        # gated on channel.has_sinks(): that read False for good, now and then, for a
        # channel a viewer subscribed to while it was being created (the mission test lost
        # every scene update in 1 run of 5 so; 0 of 8 since). It did again, ungated, in 1
        # CI run of 5 on 2026-12-04; 140 runs of a synthetic burst did not reproduce it.
        # Not traced.
        message = output.message
        channel.log(encode(message) if isinstance(message, dict) else message,
                    log_time=output.sim_time_ns)
        self.published += 1

    def _channel(self, output: Output) -> Any:
        message = output.message
        if isinstance(message, dict):
            schema = foxglove.Schema(name=f"ivfm.view{output.topic.replace('/', '.')}",
                                     encoding="jsonschema",
                                     data=json.dumps(json_schema(message)).encode())
            return foxglove.Channel(output.topic, message_encoding="json", schema=schema,
                                    context=self.context)
        typed = getattr(fg_channels, f"{type(message).__name__}Channel")
        return typed(output.topic, context=self.context)

    def close(self) -> None:
        self.server.stop()


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
    live = LiveView(host, port)
    inbox: collections.deque[tuple[str, bytes, bytes | None]] = collections.deque()
    dropped = refused = 0

    def on_sample(sample: zenoh.Sample) -> None:
        nonlocal dropped
        if len(inbox) >= MAX_INBOX:
            dropped += 1
            return
        attachment = sample.attachment
        inbox.append((str(sample.key_expr), sample.payload.to_bytes(),
                      attachment.to_bytes() if attachment is not None else None))

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
            while inbox:
                key, payload, attachment = inbox.popleft()
                try:
                    outputs = [out for record in unbatched(key, payload, attachment)
                               for out in view.feed(*record)]
                except (ValueError, TypeError, KeyError) as exc:
                    refused += 1
                    if refused == 1 or refused % 1000 == 0:
                        log(f"cannot draw a record on {key}: {exc} ({refused} so far)")
                    continue
                for output in outputs:
                    live.publish(output)
    finally:
        for sub in subscribers:
            sub.undeclare()
        session.close()
        live.close()
        log(f"stopped: {live.published} messages offered to viewers, {dropped} records "
            f"dropped (inbox full), {refused} not drawn")
    return 0
