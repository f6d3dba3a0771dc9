"""The vehicle's MAVLink server for ground tools, on UDP: sockets, peers, dispatch, streams.

Two links as PX4 SITL has them: one to a ground station (sends to 14550) and one to an
offboard API (sends to 14540); each also answers whoever talks to it. The server reads
datagrams within a budget, admits peers, hands each message to the protocol that serves
it (commands, parameters, setpoints, missions: written against link.py's ``ServerLink``,
so they never import this module) and sends the telemetry streams. Stream rates and link
failsafes run on the link clock (wall time): they serve people and tools, not the control
loop.
"""

from __future__ import annotations

import contextlib
import math
import time
from collections.abc import Callable

from autopilot.commander.commander import Commander
from autopilot.commander.rc import RcPilot
from autopilot.mavlink.ardupilot import CopterHandlers, say_banner
from autopilot.mavlink.commands import CommandProtocol
from autopilot.mavlink.link import GroundLink, Peer
from autopilot.mavlink.maintenance import reboot_vehicle
from autopilot.mavlink.mission_protocol import MissionProtocol
from autopilot.mavlink.params import ParameterProtocol
from autopilot.mavlink.setpoints import SetpointProtocol
from autopilot.mavlink.signing import (
    SigningState,
    apply_setup_signing,
    is_local,
)
from autopilot.mavlink.telemetry import (
    default_streams,
    home_items,
    home_position,
    telemetry_message,
)
from autopilot.refusal import RefusedError
from contracts.mavlink import (
    AUTOPILOT_COMPID,
    AUTOPILOT_SYSID,
    STATUSTEXT_CHUNK_BYTES,
    ardupilotmega,
    datagram_frames,
    mavlink,
    statustext_messages,
)

# Bounded ground work: a link reads what its budget allows and leaves
# the rest to the kernel, which drops what overflows its buffer; nothing a tool or a
# flood sends can cost the control loop more than the budget.
PEERS_MAX = 4  # telemetry peers per link (default of --max-peers)
PEER_SILENT_S = 3.0  # a peer not heard for this long gives its place to a newcomer
PEER_FORGET_S = 10.0  # ... and is forgotten
HEARTBEAT_SHED_S = 0.2  # heartbeats closer than this from one address are not decoded
HEARD_MAX = 256  # addresses whose last heartbeat time is remembered for that
DROP_WINDOW_S = 1.0  # drop_rate_comm is measured over this window
DROP_WARNING_S = 60.0  # at most one STATUSTEXT about drops per link per minute
DATAGRAM_MAX = 2048  # MAVLink frames are at most 280 bytes; a datagram holds a few


def decode_datagram(mav: mavlink.MAVLink, data: bytes) -> list | None:
    """The messages of one datagram, or None if any part of it is not a valid frame (or,
    with signing on, not validly signed).

    Each datagram is decoded on its own, never through pymavlink's stream buffer, so a
    broken datagram cannot spoil the next one. pymavlink records a signed frame's
    timestamp before it checks the signature; a forged frame would then make the real
    stream's next frames look old, so the record is undone when the signature fails.
    A whole frame of a message the dialect does not know comes back as the dialect's
    MAVLink_unknown (no CRC extra to check it against: never acted on, the caller skips
    and counts it), so a tool's newer message does not cost the frames beside it; with
    signing on its signature is checked all the same.
    """
    frames = datagram_frames(data)
    if frames is None:
        return None
    dialect = ardupilotmega if isinstance(mav, ardupilotmega.MAVLink) else mavlink
    signing = mav.signing.secret_key is not None
    msgs = []
    for frame in frames:
        if signing and not (frame[0] == 0xFD and frame[2] & 1):
            return None
        stream = (frame[-13], frame[5], frame[6]) if signing else None
        before = mav.signing.stream_timestamps.get(stream) if signing else None
        try:
            msg = mav.decode(bytearray(frame))
            if signing and isinstance(msg, dialect.MAVLink_unknown) and \
                    not mav.check_signature(bytearray(frame), frame[5], frame[6]):
                raise dialect.MAVError("Invalid signature")
        except dialect.MAVError:
            if signing:
                if before is None:
                    mav.signing.stream_timestamps.pop(stream, None)
                else:
                    mav.signing.stream_timestamps[stream] = before
            return None
        msgs.append(msg)
    return msgs


class MavlinkServer:
    """Serves every ground link of one vehicle."""

    def __init__(self, vehicle: Commander, links: list[GroundLink], flavour: str = "px4",
                 clock: Callable[[], float] = time.monotonic,
                 sysid: int = AUTOPILOT_SYSID, max_peers: int = PEERS_MAX,
                 signing_state: SigningState | None = None) -> None:
        if not 0 <= max_peers <= 64:
            raise ValueError(f"max peers must be in [0, 64], got {max_peers}")
        self.vehicle = vehicle
        self.max_peers = max_peers
        self.sysid = sysid
        # Per message sent to tools (the Zenoh MAVLink mirror), per text said (the log).
        self.on_sent: Callable[[GroundLink, object, bytes], None] | None = None
        self.on_said: Callable[[int, str], None] | None = None
        self.links = links
        self.signing_state = signing_state  # signing clock and streams across restarts
        self.flavour = flavour
        self.clock = clock
        self.boot_s = clock()
        self._shown: tuple | None = None  # (armed, mode) last announced
        self._text_id = 0  # of the last chunked STATUSTEXT (1-65535)
        self.reboot_pending = False
        self._home_sent = None  # the home last announced (ArduPilot: HOME_POSITION on change)
        self.commands = CommandProtocol(self)
        self.parameters = ParameterProtocol(self)
        self.setpoints = SetpointProtocol(self)
        self.missions = MissionProtocol(self)
        # The ArduPilot flavour's RC channels: sticks, mode switch, radio failsafe.
        self.rc_pilot = RcPilot(vehicle, vehicle.inputs.rc, vehicle.state) \
            if flavour == "ardupilot" else None
        # Message type -> handler(link, address, msg, now); what is not here is ignored.
        self.handlers: dict[str, Callable] = {
            "HEARTBEAT": self._on_heartbeat, "PING": self._on_ping,
            "TIMESYNC": self._on_timesync, "SETUP_SIGNING": self._on_setup_signing,
            **self.commands.handlers(),
            **self.parameters.handlers(), **self.setpoints.handlers(),
            **self.missions.handlers()}
        if flavour == "ardupilot":
            self.handlers.update(CopterHandlers(
                self, self.handlers["PARAM_REQUEST_LIST"]).handlers())

    # -- receiving -----------------------------------------------------------------------
    def receive(self, link: GroundLink, budget_s: float = math.inf,
                max_datagrams: int = 10_000) -> int:
        """Read and handle datagrams waiting on the link until ``budget_s`` of wall time
        (or ``max_datagrams``) is spent; what is left waits in the kernel's buffer.
        Returns the number of datagrams read."""
        end = time.perf_counter() + budget_s
        now = self.clock()  # one reading for the batch: the link clock counts seconds
        c = link.counters
        sock = link.sock
        n = 0
        while n < max_datagrams:
            try:
                data, address = sock.recvfrom(DATAGRAM_MAX)
            except (BlockingIOError, InterruptedError):
                break
            except OSError:  # ICMP port unreachable from a tool that went away
                n += 1
                continue
            n += 1
            c.datagrams += 1
            if data and (data[0] == 0xFD or data[0] == 0xFE):
                if self._datagram(link, data, address, now) and time.perf_counter() >= end:
                    break  # a decoded datagram may have cost a reply: look at the clock
            else:
                c.rejected += 1  # not MAVLink: refused at its first byte
            if n % 8 == 0 and time.perf_counter() >= end:
                break
        return n

    def _datagram(self, link: GroundLink, data: bytes, address: tuple[str, int],
                  now: float) -> bool:
        """Handle one datagram; False if it was refused or shed without decoding."""
        c = link.counters
        # A HEARTBEAT only says "still here": one per address per HEARTBEAT_SHED_S is
        # decoded, the rest cost a dictionary lookup (a flood of them stays cheap).
        heartbeat = (len(data) >= 12 and data[0] == 0xFD and data[7:10] == b"\0\0\0"
                     and len(data) == 12 + data[1] + (13 if data[2] & 1 else 0))
        if heartbeat:
            heard = link.heartbeat_heard_s.get(address)
            if heard is not None and now - heard < HEARTBEAT_SHED_S:
                c.shed += 1
                return False
        msgs = decode_datagram(link.mav, data)
        if msgs is None:
            c.rejected += 1
            return True
        if heartbeat:
            link.heartbeat_heard_s[address] = now
            link.heartbeat_heard_s.move_to_end(address)
            if len(link.heartbeat_heard_s) > HEARD_MAX:
                link.heartbeat_heard_s.popitem(last=False)
        for msg in msgs:
            if msg.get_type().startswith("UNKNOWN_"):  # pymavlink's MAVLink_unknown
                c.unknown += 1
                continue
            c.frames += 1
            if not self._for_us(msg):
                c.not_for_us += 1
                continue
            self._admit(link, address, now, interactive=not heartbeat)
            handler = self.handlers.get(msg.get_type())
            if handler is not None:
                handler(link, address, msg, now)
        return True

    def _admit(self, link: GroundLink, address: tuple[str, int], now: float,
               interactive: bool) -> None:
        """``address`` sent a valid frame for us: it hears our telemetry, within
        ``max_peers``. A full table gives a newcomer the place of its quietest peer only
        if that one has been silent for PEER_SILENT_S (PEER_FORGET_S for a peer that has
        sent commands or requests), so a burst of new addresses cannot push out a tool
        that keeps talking, even when the burst costs it a few datagrams."""
        peer = link.peers.get(address)
        if peer is not None:
            peer.heard_s = now
            peer.interactive = peer.interactive or interactive
            return
        if len(link.peers) >= self.max_peers:
            silent = [p for p in link.peers.values() if now - p.heard_s >= (
                PEER_FORGET_S if p.interactive else PEER_SILENT_S)]
            if not silent:
                link.counters.peers_refused += 1
                return
            del link.peers[min(silent, key=lambda p: p.heard_s).address]
        link.peers[address] = Peer(address, now, interactive)

    def _for_us(self, msg) -> bool:
        """Broadcast (no target, or system 0) or addressed to this system; never our own
        frames coming back."""
        if msg.get_srcSystem() == self.sysid and msg.get_srcComponent() == AUTOPILOT_COMPID:
            return False
        target = getattr(msg, "target_system", 0)
        return target in (0, self.sysid)

    def send(self, link: GroundLink, msg, address=None) -> None:
        data = msg.pack(link.mav)
        if self.on_sent is not None:
            self.on_sent(link, msg, data)
        for target in [address] if address is not None else link.targets():
            with contextlib.suppress(OSError):  # nobody listening there (yet)
                link.sock.sendto(data, target)

    def broadcast(self, msg_factory: Callable[[], object]) -> None:
        for link in self.links:
            self.send(link, msg_factory())

    def send_text(self, link: GroundLink | None, severity: int, text: str,
                  address=None) -> None:
        """A STATUSTEXT to one link (``address`` on it), or to every link (``link`` None);
        a text longer than 50 bytes goes in chunks (contracts/mavlink.py)."""
        chunk_id = 0
        if len(text.encode()) > STATUSTEXT_CHUNK_BYTES:
            self._text_id = self._text_id % 65535 + 1
            chunk_id = self._text_id
        for msg in statustext_messages(severity, text, chunk_id):
            for target in self.links if link is None else [link]:
                self.send(target, msg, address)

    # -- small protocols -----------------------------------------------------------------
    def _on_heartbeat(self, link, address, msg, now) -> None:
        if msg.type == mavlink.MAV_TYPE_GCS or msg.get_srcComponent() == \
                mavlink.MAV_COMP_ID_MISSIONPLANNER:
            self.vehicle.inputs.gcs_heartbeat(now)

    def _on_ping(self, link, address, msg, now) -> None:
        if msg.target_system == 0:
            self.send(link, mavlink.MAVLink_ping_message(
                msg.time_usec, msg.seq, msg.get_srcSystem(), msg.get_srcComponent()), address)

    def _on_timesync(self, link, address, msg, now) -> None:
        if msg.tc1 == 0:
            self.send(link, mavlink.MAVLink_timesync_message(
                int((now - self.boot_s) * 1e9), msg.ts1), address)

    def _reboot(self) -> None:
        """The acknowledged reboot: the vehicle's state restarts, every link streams what
        it streams at boot, and the boot texts are said again (Copter's banner)."""
        self.reboot_pending = False
        try:
            reboot_vehicle(self.vehicle)
        except RefusedError:  # armed by a command read after the reboot's, before now
            self.send_text(None, mavlink.MAV_SEVERITY_WARNING, "reboot cancelled: armed")
            return
        self.announce()  # "rebooted" before the boot texts
        self._home_sent = None
        for link in self.links:
            link.intervals_s = default_streams(self.flavour)
            link.next_due_s.clear()
        if self.flavour == "ardupilot":
            say_banner(self, None)

    def _on_setup_signing(self, link, address, msg, now) -> None:
        """SETUP_SIGNING: only over a signed link (with signing on, an unsigned frame never
        gets here) or from this machine; a key never crosses a network in the clear."""
        if msg.target_system != self.sysid:
            return
        if link.mav.signing.secret_key is None and not is_local(address):
            self.send_text(link, 4, "SETUP_SIGNING refused: only over a signed link or from "
                           "this machine", address)
            return
        try:
            text = apply_setup_signing([lk.mav.signing for lk in self.links],
                                       bytes(msg.secret_key), msg.initial_timestamp)
        except ValueError as exc:
            self.send_text(link, 4, str(exc), address)
            return
        self.send_text(link, 5, text, address)

    def save_signing(self, force: bool = False) -> None:
        """Persist the signing clock and streams (at most once a second; ``force``: now)."""
        signings = [link.mav.signing for link in self.links]
        if self.signing_state is not None and any(s.secret_key for s in signings):
            self.signing_state.save(signings, self.clock(), force)

    # -- telemetry -----------------------------------------------------------------------
    def announce(self) -> None:
        """Send what the vehicle said (STATUSTEXT), and hand it to ``on_said``. The loop
        calls it after each control step, so a text goes out, and into the log, at the
        sim time it was said; ``service`` calls it for what was said between steps."""
        while self.vehicle.messages:
            severity, text = self.vehicle.messages.pop(0)
            if self.on_said is not None:
                self.on_said(severity, text)
            self.send_text(None, severity, text)

    def service(self) -> None:
        """Send what is due and queued; check the link failsafes."""
        now = self.clock()
        if self.reboot_pending:
            self._reboot()
        v = self.vehicle
        if self.flavour == "ardupilot" and v.home_known and v.places != self._home_sent:
            self._home_sent = v.places  # Copter sends HOME_POSITION when home is set
            self.broadcast(lambda: home_position(v.places))
        self.vehicle.check_links(now)
        if self.rc_pilot is not None:
            self.rc_pilot.check(now)
        self.missions.service(now)
        shown = (self.vehicle.armed, self.vehicle.mode)
        if shown != self._shown:  # tools read arming and mode off heartbeats
            self._shown = shown
            for link in self.links:
                link.next_due_s[mavlink.MAVLINK_MSG_ID_HEARTBEAT] = now
                link.next_due_s[mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE] = now
        self.announce()
        self.save_signing()
        while self.vehicle.reached:
            seq = self.vehicle.reached.pop(0) + home_items(self.flavour)
            self.broadcast(lambda q=seq: mavlink.MAVLink_mission_item_reached_message(q))
            for link in self.links:  # the current item changes with it
                link.next_due_s[mavlink.MAVLINK_MSG_ID_MISSION_CURRENT] = now
        for link in self.links:
            for peer in [a for a, p in link.peers.items() if now - p.heard_s > PEER_FORGET_S]:
                del link.peers[peer]
            self._measure_drops(link, now)
            for msg_id, interval in link.intervals_s.items():
                due = link.next_due_s.get(msg_id, now)
                if now >= due:
                    self.send(link, self.telemetry(msg_id))
                    link.next_due_s[msg_id] = max(due + interval, now)

    def _measure_drops(self, link: GroundLink, now: float) -> None:
        """drop_rate_comm over the last window; a STATUSTEXT at most once a minute."""
        if link.window is not None and now - link.window[0] < DROP_WINDOW_S:
            return
        link.read_kernel_drops()
        arrived, lost = link.lost()
        if link.window is None:
            link.window = (now, arrived, lost)
            return
        _start, arrived0, lost0 = link.window
        link.window = (now, arrived, lost)
        new_lost = lost - lost0
        link.drop_rate = new_lost / max(1, arrived - arrived0)
        if new_lost and now - link.warned_s >= DROP_WARNING_S:
            link.warned_s = now
            c = link.counters
            self.send_text(None, mavlink.MAV_SEVERITY_WARNING,
                           f"{link.name}: {100 * link.drop_rate:.0f}% of datagrams lost "
                           f"({c.kernel_drops} dropped, {c.rejected} bad)")

    def link_status(self) -> dict[str, dict]:
        """Per link: counters, drop rate and peers (for status records and logs)."""
        for link in self.links:
            link.read_kernel_drops()
        return {link.name: {**link.counters.as_dict(), "drop_rate": round(link.drop_rate, 4),
                            "peers": len(link.peers)} for link in self.links}

    def telemetry(self, msg_id: int, boot_ms: int | None = None):
        """A telemetry message; its ``time_boot_ms`` is the vehicle's sim time, as PX4
        SITL's clock is the simulator's, so that a tool times the flight as the vehicle
        flies it (a simulator that started late or stalled runs behind the wall clock)."""
        if boot_ms is None:
            boot_ms = round(self.vehicle.sim_t_s * 1000) & 0xFFFFFFFF
        drop = max((ln.drop_rate for ln in self.links), default=0.0)
        errors = sum(ln.counters.rejected for ln in self.links)
        return telemetry_message(msg_id, self.vehicle, self.flavour, boot_ms, drop, errors)
