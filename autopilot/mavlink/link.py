"""One ground link (its UDP socket, parser and peers) and what the message handlers see of
the server that serves the links.

The handlers (commands.py, mission_protocol.py, params.py, setpoints.py) are written
against :class:`ServerLink`, not the server itself: the server (server.py) imports them
and hands itself in, so the dependency runs one way.
"""

from __future__ import annotations

import math
import socket
import struct
from collections import OrderedDict
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Protocol

from autopilot.mavlink.signing import signing_clock_now
from autopilot.mavlink.telemetry import DEFAULT_STREAMS, default_streams
from contracts.mavlink import AUTOPILOT_COMPID, AUTOPILOT_SYSID, mavlink, new_mavlink

if TYPE_CHECKING:
    from autopilot.commander.commander import Commander

SO_MEMINFO = 55  # Linux: the socket's memory figures; index 8 counts the datagrams dropped
SK_MEMINFO_DROPS = 8
SO_RCVBUFFORCE = getattr(socket, "SO_RCVBUFFORCE", 33)
RCVBUF_BYTES = 1 << 20


@dataclass
class Peer:
    address: tuple[str, int]
    heard_s: float
    interactive: bool = False  # has sent more than HEARTBEATs: a tool, not a bystander


@dataclass
class LinkCounters:
    """What a link has read, refused, shed and lost (cumulative)."""

    datagrams: int = 0  # read from the socket
    frames: int = 0  # valid frames decoded
    rejected: int = 0  # not MAVLink, bad CRC, unsigned or wrongly signed
    unknown: int = 0  # whole frames of a message the dialect does not know: skipped
    shed: int = 0  # heartbeats not decoded (the same address was heard just now)
    not_for_us: int = 0  # valid frames for another system
    kernel_drops: int = 0  # datagrams the kernel dropped: its buffer was full
    peers_refused: int = 0  # newcomers turned away while every peer was talking

    def as_dict(self) -> dict[str, int]:
        return dict(self.__dict__)


@dataclass
class GroundLink:
    """One UDP socket: its parser/encoder (sequence, signing) and who listens."""

    name: str
    sock: socket.socket
    default_remote: tuple[str, int] | None
    mav: mavlink.MAVLink
    intervals_s: dict[int, float] = field(default_factory=lambda: dict(DEFAULT_STREAMS))
    next_due_s: dict[int, float] = field(default_factory=dict)
    peers: dict[tuple[str, int], Peer] = field(default_factory=dict)
    counters: LinkCounters = field(default_factory=LinkCounters)
    heartbeat_heard_s: OrderedDict[tuple[str, int], float] = field(default_factory=OrderedDict)
    drop_rate: float = 0.0  # lost / arrived over the last window (0-1)
    window: tuple[float, int, int] | None = None  # (start, arrived, lost) at its start
    warned_s: float = -math.inf

    def targets(self) -> list[tuple[str, int]]:
        out = list(self.peers)
        if self.default_remote is not None and self.default_remote not in self.peers:
            out.append(self.default_remote)
        return out

    def read_kernel_drops(self) -> None:
        """Datagrams the kernel dropped for want of buffer (Linux; elsewhere 0)."""
        drops = kernel_drops(self.sock)
        if drops is not None:
            self.counters.kernel_drops = drops

    def lost(self) -> tuple[int, int]:
        """(arrived, lost): datagrams that reached the socket, and those the kernel dropped
        or the link refused (as of the last read_kernel_drops)."""
        c = self.counters
        return c.datagrams + c.kernel_drops, c.kernel_drops + c.rejected


def kernel_drops(sock: socket.socket) -> int | None:
    """Datagrams the kernel dropped at ``sock`` for want of buffer (None: not Linux)."""
    try:
        info = sock.getsockopt(socket.SOL_SOCKET, SO_MEMINFO, 4 * (SK_MEMINFO_DROPS + 1))
    except OSError:
        return None
    if len(info) < 4 * (SK_MEMINFO_DROPS + 1):
        return None
    return struct.unpack_from("I", info, 4 * SK_MEMINFO_DROPS)[0]


def open_link(name: str, bind: tuple[str, int], remote: tuple[str, int] | None,
              signing_key: bytes | None, link_id: int,
              sysid: int = AUTOPILOT_SYSID, flavour: str = "px4") -> GroundLink:
    """A ground link's socket and its encoder/parser in the flavour's dialect."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:  # room for a burst between two reads (privileged: past the system's rmem_max)
        sock.setsockopt(socket.SOL_SOCKET, SO_RCVBUFFORCE, RCVBUF_BYTES)
    except OSError:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, RCVBUF_BYTES)
    sock.bind(bind)
    sock.setblocking(False)
    mav = new_mavlink(sysid, AUTOPILOT_COMPID, flavour)
    mav.signing.link_id = link_id  # also for a key SETUP_SIGNING sets later
    mav.signing.timestamp = signing_clock_now()
    if signing_key is not None:
        mav.signing.secret_key = signing_key
        mav.signing.sign_outgoing = True
        mav.signing.allow_unsigned_callback = None
    return GroundLink(name, sock, remote, mav, default_streams(flavour))


class ServerLink(Protocol):
    """What a message handler sees of the MAVLink server: the vehicle it serves, how it
    presents itself, its links, and sending on them."""

    vehicle: Commander
    flavour: str  # "px4" or "ardupilot"
    links: list[GroundLink]
    reboot_pending: bool  # a reboot acknowledged: the server restarts the vehicle next

    def send(self, link: GroundLink, msg: object,
             address: tuple[str, int] | None = None) -> None:
        """Send ``msg`` to ``address`` on ``link``, or to every target of the link."""
        ...

    def send_text(self, link: GroundLink | None, severity: int, text: str,
                  address: tuple[str, int] | None = None) -> None:
        """A STATUSTEXT to one link (``address`` on it), or to every link (``link`` None)."""
        ...

    def telemetry(self, msg_id: int, boot_ms: int | None = None) -> object:
        """The telemetry message ``msg_id`` as the streams send it."""
        ...
