"""The simulator's end of PX4's simulator protocol: a TCP listener for one autopilot at a
time, the connection to it and what the simulator measures about it.

The MAVLink object that encodes the samples (``mav``, for ``SampleSource.frames``) also
parses what comes back; it is made anew for each connection, so a half message from the
last one does not linger (and the sequence numbers of a connection's samples start at
0). The samples are packed in compiled code
(``contracts/sim_samples.py``); the autopilot's motor commands are read in compiled code
(``contracts/sim_readings.py``), everything else through pymavlink.
"""

from __future__ import annotations

import math
import selectors
import socket
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from contracts import SITL, timeline
from contracts.mavlink import (
    HIL_MOTORS,
    SIMULATOR_COMPID,
    SIMULATOR_SYSID,
    new_mavlink,
    split_frames,
)
from contracts.realtime import Histogram
from contracts.sim_readings import FrameReader


@dataclass
class LinkStats:
    """What the simulator measures about the autopilot (real time mostly)."""

    samples_sent: int = 0
    commands_received: int = 0
    bad_messages: int = 0
    periods_without_command: int = 0
    latency: Histogram = field(default_factory=Histogram)  # sample -> its answer [s]


class Actuators(NamedTuple):
    """A HIL_ACTUATOR_CONTROLS decoded and checked: the motor commands it gives."""

    time_usec: int
    commands: np.ndarray

    def get_type(self) -> str:
        return "HIL_ACTUATOR_CONTROLS"


EVERY_MESSAGE = np.zeros(0, dtype=np.int64)  # the reader's wanted ids: every message
_NO_HOME = np.zeros(3)


class AutopilotLink:
    """The listening socket, the MAVLink state of the connection in use, and the reading
    of what the autopilot sends (bad bytes counted in ``stats``)."""

    def __init__(self, host: str, port: int, stats: LinkStats,
                 log: Callable[[str], None]) -> None:
        self.host = host
        self.port = port
        self.stats = stats
        self.log = log
        self.mav = new_mavlink(SIMULATOR_SYSID, SIMULATOR_COMPID)
        self._pending = b""  # the start of a frame whose end has not come yet
        self._reader = FrameReader(
            lambda kind, time_us, row: Actuators(time_us, row[:HIL_MOTORS].copy()))
        self._server: socket.socket | None = None

    def listen(self) -> int:
        """Open the listening socket (accepts time out after 0.2 s); the port it has."""
        self._server = socket.create_server((self.host, self.port), reuse_port=False)
        self._server.settimeout(0.2)
        return self._server.getsockname()[1]

    def stop_blocking(self) -> None:
        """Real time: accepting never waits, the loop polls once a period."""
        self._server.setblocking(False)

    def close(self) -> None:
        self._server.close()

    def accept(self, time_us: int) -> socket.socket | None:
        """A new autopilot's connection, or None if none is waiting."""
        try:
            conn, peer = self._server.accept()
        except (TimeoutError, BlockingIOError):
            return None
        conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        timeline.mark(SITL, "autopilot connected")
        self.log(f"autopilot connected from {peer[0]}:{peer[1]} at t={time_us / 1e6:.3f} s")
        # A fresh parser per connection: a half message from the last one must not linger.
        self.mav = new_mavlink(SIMULATOR_SYSID, SIMULATOR_COMPID)
        self._pending = b""
        return conn

    def read(self, conn: socket.socket) -> list | None:
        """Messages available now; None when the autopilot has gone. A plain motor
        command comes as ``Actuators`` (decoded and checked in compiled code,
        contracts/sim_readings.py), anything else as pymavlink parses it."""
        try:
            data = conn.recv(65536)
        except (BlockingIOError, TimeoutError):
            return []
        except OSError:
            return None
        if not data:
            return None
        return self.messages_of(self._pending + data)

    def messages_of(self, data: bytes) -> list:
        """The messages in ``data`` (what came after the last frame cut off); a frame cut
        off at its end waits for the next read."""
        if self.mav.signing.secret_key is not None:  # pymavlink checks signatures
            frames, self._pending = split_frames(data)
            return self._judged(self.mav.parse_buffer(b"".join(f for _, f in frames)) or [])
        msgs, self._pending = self._reader.read(data, EVERY_MESSAGE, _NO_HOME, self.mav)
        return self._judged(msgs)

    def _judged(self, parsed: list) -> list:
        """The messages of one read, its BAD_DATA counted and said (once), not passed
        on."""
        msgs, bad = [], []
        for msg in parsed:
            (bad if msg.get_type() == "BAD_DATA" else msgs).append(msg)
        if bad:
            self.stats.bad_messages += len(bad)
            self.log(f"unreadable bytes from the autopilot: {bad[0].reason}")
        return msgs

    def lost(self, conn: socket.socket, time_us: int) -> None:
        conn.close()
        self.log(f"autopilot disconnected at t={time_us / 1e6:.3f} s")


class RealtimeConnection:
    """Real time: the autopilot's connection (None while away) and what its commands did."""

    def __init__(self) -> None:
        self.conn: socket.socket | None = None
        self.sel = selectors.DefaultSelector()
        self.got_command = False  # in the period under way
        self.last_command_s = -math.inf  # sim time
        self.timed_out = True  # no commands (yet, or for longer than the ESC timeout)

    def attach(self, conn: socket.socket) -> None:
        conn.setblocking(False)
        self.sel.register(conn, selectors.EVENT_READ)
        self.conn = conn
