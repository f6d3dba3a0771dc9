"""The autopilot as a MAVLink vehicle for ground tools, on UDP (SPEC section 7).

Two links as PX4 SITL has them: one to a ground station (sends to 14550) and one to an
offboard API (sends to 14540); each also answers whoever talks to it. This module maps
MAVLink to :class:`autopilot.vehicle.Vehicle` calls and the vehicle's state to
telemetry. Telemetry rates run on the link clock (wall time): they serve people and
tools, not the control loop.
"""

from __future__ import annotations

import contextlib
import importlib.metadata
import math
import socket
import struct
import time
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from autopilot.control.parameters import PARAMETER_SPECS, PARAMETERS
from autopilot.offboard import global_setpoint, local_setpoint
from autopilot.vehicle import RefusedError, Vehicle
from contracts.frames import HOME_ALT_AMSL_M, HOME_LAT_DEG, HOME_LON_DEG, geodetic_from_ned
from contracts.frames import quat_from_euler as _quat_from_euler
from contracts.mavlink import (
    AUTOPILOT_COMPID,
    AUTOPILOT_SYSID,
    datagram_frames,
    mavlink,
    new_mavlink,
)
from contracts.modes import FlightMode, custom_mode, mode_from_custom, px4_custom_mode_from_command
from contracts.vectors import MEAS_EULER, MEAS_VEL, MEAS_VZ, MEAS_YAW, MEAS_Z, MEASUREMENT

FORCE_DISARM_MAGIC = 21196
PARAM_COUNT = len(PARAMETERS)
PARAM_INDEX = {spec.name: i for i, spec in enumerate(PARAMETERS)}


def firmware_version(version: str) -> int:
    """AUTOPILOT_VERSION's flight_sw_version of a "major.minor.patch" package version: one
    byte each, then 0xFF (a release), as PX4 packs it."""
    major, minor, patch = (int(part) for part in (version.split(".") + ["0", "0"])[:3])
    return (major << 24) | (minor << 16) | (patch << 8) | 0xFF


FIRMWARE_VERSION = firmware_version(importlib.metadata.version("ivfm-sitl"))

# Attitude-target type_mask bits (ATTITUDE_TARGET_TYPEMASK).
BODY_RATES_IGNORE = 0b111
THRUST_IGNORE = 1 << 6
ATTITUDE_IGNORE = 1 << 7

SENSORS = (mavlink.MAV_SYS_STATUS_SENSOR_3D_GYRO | mavlink.MAV_SYS_STATUS_SENSOR_3D_ACCEL
           | mavlink.MAV_SYS_STATUS_SENSOR_3D_MAG | mavlink.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
           | mavlink.MAV_SYS_STATUS_SENSOR_GPS | mavlink.MAV_SYS_STATUS_SENSOR_ANGULAR_RATE_CONTROL
           | mavlink.MAV_SYS_STATUS_SENSOR_ATTITUDE_STABILIZATION
           | mavlink.MAV_SYS_STATUS_SENSOR_YAW_POSITION
           | mavlink.MAV_SYS_STATUS_SENSOR_Z_ALTITUDE_CONTROL
           | mavlink.MAV_SYS_STATUS_SENSOR_XY_POSITION_CONTROL
           | mavlink.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS | mavlink.MAV_SYS_STATUS_AHRS)
PREARM = mavlink.MAV_SYS_STATUS_PREARM_CHECK

# Telemetry every link streams, message id -> default interval [s].
DEFAULT_STREAMS: dict[int, float] = {
    mavlink.MAVLINK_MSG_ID_HEARTBEAT: 1.0,
    mavlink.MAVLINK_MSG_ID_SYS_STATUS: 1.0,
    mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: 1.0,
    mavlink.MAVLINK_MSG_ID_ATTITUDE: 0.05,
    mavlink.MAVLINK_MSG_ID_ATTITUDE_QUATERNION: 0.05,
    mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED: 0.05,
    mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: 0.1,
    mavlink.MAVLINK_MSG_ID_HOME_POSITION: 5.0,
    mavlink.MAVLINK_MSG_ID_VFR_HUD: 0.25,
}
# What REQUEST_MESSAGE and SET_MESSAGE_INTERVAL can have, beyond the streams.
PRODUCIBLE = set(DEFAULT_STREAMS) | {mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION}


# Bounded ground work (SPEC section 8): a link reads what its budget allows and leaves
# the rest to the kernel, which drops what overflows its buffer; nothing a tool or a
# flood sends can cost the control loop more than the budget.
PEERS_MAX = 4  # telemetry peers per link (default of --max-peers)
PEER_SILENT_S = 3.0  # a peer not heard for this long gives its place to a newcomer
PEER_FORGET_S = 10.0  # ... and is forgotten
HEARTBEAT_SHED_S = 0.2  # heartbeats closer than this from one address are not decoded
HEARD_MAX = 256  # addresses whose last heartbeat time is remembered for that
DROP_WINDOW_S = 1.0  # drop_rate_comm is measured over this window
DROP_WARNING_S = 60.0  # at most one STATUSTEXT about drops per link per minute
SO_MEMINFO = 55  # Linux: the socket's memory figures; index 8 counts the datagrams dropped
SK_MEMINFO_DROPS = 8
SO_RCVBUFFORCE = getattr(socket, "SO_RCVBUFFORCE", 33)
RCVBUF_BYTES = 1 << 20
DATAGRAM_MAX = 2048  # MAVLink frames are at most 280 bytes; a datagram holds a few


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
    rejected: int = 0  # not MAVLink, bad CRC, unsigned or wrongly signed, unknown message
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
        try:
            info = self.sock.getsockopt(socket.SOL_SOCKET, SO_MEMINFO, 4 * (SK_MEMINFO_DROPS + 1))
        except OSError:
            return
        if len(info) >= 4 * (SK_MEMINFO_DROPS + 1):
            self.counters.kernel_drops = struct.unpack_from("I", info, 4 * SK_MEMINFO_DROPS)[0]

    def lost(self) -> tuple[int, int]:
        """(arrived, lost): datagrams that reached the socket, and those the kernel dropped
        or the link refused (as of the last read_kernel_drops)."""
        c = self.counters
        return c.datagrams + c.kernel_drops, c.kernel_drops + c.rejected


def open_link(name: str, bind: tuple[str, int], remote: tuple[str, int] | None,
              signing_key: bytes | None, link_id: int,
              sysid: int = AUTOPILOT_SYSID) -> GroundLink:
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:  # room for a burst between two reads (privileged: past the system's rmem_max)
        sock.setsockopt(socket.SOL_SOCKET, SO_RCVBUFFORCE, RCVBUF_BYTES)
    except OSError:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, RCVBUF_BYTES)
    sock.bind(bind)
    sock.setblocking(False)
    mav = new_mavlink(sysid, AUTOPILOT_COMPID)
    if signing_key is not None:
        mav.signing.secret_key = signing_key
        mav.signing.link_id = link_id
        mav.signing.sign_outgoing = True
        # MAVLink's signing clock: 10 us units since 2015-01-01.
        mav.signing.timestamp = int((time.time() - 1420070400) * 100000)
        mav.signing.allow_unsigned_callback = None
    return GroundLink(name, sock, remote, mav)


def decode_datagram(mav: mavlink.MAVLink, data: bytes) -> list | None:
    """The messages of one datagram, or None if any part of it is not a valid frame (or,
    with signing on, not validly signed).

    Each datagram is decoded on its own, never through pymavlink's stream buffer, so a
    broken datagram cannot spoil the next one. pymavlink records a signed frame's
    timestamp before it checks the signature; a forged frame would then make the real
    stream's next frames look old, so the record is undone when the signature fails.
    """
    frames = datagram_frames(data)
    if frames is None:
        return None
    signing = mav.signing.secret_key is not None
    msgs = []
    for frame in frames:
        if signing and not (frame[0] == 0xFD and frame[2] & 1):
            return None
        stream = (frame[-13], frame[5], frame[6]) if signing else None
        before = mav.signing.stream_timestamps.get(stream) if signing else None
        try:
            msg = mav.decode(bytearray(frame))
        except mavlink.MAVError:
            if signing:
                if before is None:
                    mav.signing.stream_timestamps.pop(stream, None)
                else:
                    mav.signing.stream_timestamps[stream] = before
            return None
        if isinstance(msg, mavlink.MAVLink_unknown):
            return None  # no CRC extra to check it against: not trusted
        msgs.append(msg)
    return msgs


class GroundStation:
    """Serves every ground link: commands, parameters, setpoints, telemetry."""

    def __init__(self, vehicle: Vehicle, links: list[GroundLink], flavour: str = "px4",
                 clock: Callable[[], float] = time.monotonic,
                 sysid: int = AUTOPILOT_SYSID, max_peers: int = PEERS_MAX) -> None:
        if not 0 <= max_peers <= 64:
            raise ValueError(f"max peers must be in [0, 64], got {max_peers}")
        self.vehicle = vehicle
        self.max_peers = max_peers
        self.sysid = sysid
        # Called once per message sent to tools (the Zenoh MAVLink mirror listens here).
        self.on_sent: Callable[[GroundLink, object, bytes], None] | None = None
        self.links = links
        self.flavour = flavour
        self.clock = clock
        self.boot_s = clock()
        self.mav_autopilot = (mavlink.MAV_AUTOPILOT_PX4 if flavour == "px4"
                              else mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA)
        self.commands_handled = 0
        self._shown: tuple | None = None  # (armed, mode) last announced
        self._last_refusal_s = -math.inf

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
            c.frames += 1
            if not self._for_us(msg):
                c.not_for_us += 1
                continue
            self._admit(link, address, now, interactive=not heartbeat)
            handler = getattr(self, f"_on_{msg.get_type().lower()}", None)
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

    def _send(self, link: GroundLink, msg, address=None) -> None:
        data = msg.pack(link.mav)
        if self.on_sent is not None:
            self.on_sent(link, msg, data)
        for target in [address] if address is not None else link.targets():
            with contextlib.suppress(OSError):  # nobody listening there (yet)
                link.sock.sendto(data, target)

    def broadcast(self, msg_factory: Callable[[], object]) -> None:
        for link in self.links:
            self._send(link, msg_factory())

    # -- handlers ------------------------------------------------------------------------
    def _on_heartbeat(self, link, address, msg, now) -> None:
        if msg.type == mavlink.MAV_TYPE_GCS or msg.get_srcComponent() == \
                mavlink.MAV_COMP_ID_MISSIONPLANNER:
            self.vehicle.gcs_heartbeat(now)

    def _ack(self, link, address, msg, command: int, result: int, text: str | None = None):
        self._send(link, mavlink.MAVLink_command_ack_message(
            command, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent()), address)
        if text:
            severity = 6 if result == mavlink.MAV_RESULT_ACCEPTED else 4
            self._send(link, mavlink.MAVLink_statustext_message(severity, text.encode()[:50]),
                       address)

    def _on_command_long(self, link, address, msg, now) -> None:
        params = [msg.param1, msg.param2, msg.param3, msg.param4, msg.param5, msg.param6,
                  msg.param7]
        self._command(link, address, msg, msg.command, params, now)

    def _on_command_int(self, link, address, msg, now) -> None:
        params = [msg.param1, msg.param2, msg.param3, msg.param4, msg.x * 1e-7, msg.y * 1e-7,
                  msg.z]
        self._command(link, address, msg, msg.command, params, now)

    def _command(self, link, address, msg, command: int, params: list[float], now: float):
        self.commands_handled += 1
        handler = COMMANDS.get(command)
        if handler is None:
            self._ack(link, address, msg, command, mavlink.MAV_RESULT_UNSUPPORTED)
            return
        try:
            text = handler(self, link, address, params, now)
        except RefusedError as exc:
            result = (mavlink.MAV_RESULT_TEMPORARILY_REJECTED if exc.temporary
                      else mavlink.MAV_RESULT_DENIED)
            self._ack(link, address, msg, command, result, str(exc))
            return
        self._ack(link, address, msg, command, mavlink.MAV_RESULT_ACCEPTED)
        if isinstance(text, list):  # messages to send after the ACK
            for reply in text:
                self._send(link, reply, address)

    def _on_set_mode(self, link, address, msg, now) -> None:
        # Deprecated but sent by older tools (MAVProxy for ArduPilot); acknowledged as
        # DO_SET_MODE, as ArduPilot does.
        self._command(link, address, msg, mavlink.MAV_CMD_DO_SET_MODE,
                      [float(msg.base_mode), float(msg.custom_mode), 0.0, 0, 0, 0, 0], now)

    def _on_param_request_list(self, link, address, msg, now) -> None:
        for spec in PARAMETERS:
            self._send(link, self._param_value(spec.name), address)

    def _on_param_request_read(self, link, address, msg, now) -> None:
        name = msg.param_id.rstrip("\x00") if msg.param_index < 0 else (
            PARAMETERS[msg.param_index].name if msg.param_index < PARAM_COUNT else "")
        if name not in PARAM_INDEX:
            self._send(link, mavlink.MAVLink_statustext_message(
                4, f"unknown parameter {name or msg.param_index}".encode()[:50]), address)
            return
        self._send(link, self._param_value(name), address)

    def _on_param_set(self, link, address, msg, now) -> None:
        name = msg.param_id.rstrip("\x00")
        if name in PARAM_INDEX:
            try:
                self.vehicle.set_parameter(name, msg.param_value)
            except RefusedError as exc:
                self._send(link, mavlink.MAVLink_statustext_message(
                    4, f"{name}: {exc}".encode()[:50]), address)
            # PARAM_VALUE either way: the tool learns the value in force.
            value = self._param_value(name)
            for target_link in self.links:
                self._send(target_link, value)
        else:
            self._send(link, mavlink.MAVLink_statustext_message(
                4, f"unknown parameter {name}".encode()[:50]), address)

    def _param_value(self, name: str):
        return mavlink.MAVLink_param_value_message(
            name.encode(), float(self.vehicle.parameters[name]), mavlink.MAV_PARAM_TYPE_REAL32,
            PARAM_COUNT, PARAM_INDEX[name])

    def _on_file_transfer_protocol(self, link, address, msg, now) -> None:
        # No MAVLink FTP: a NAK (opcode 129, error 4 "Unsupported") so tools fall back to
        # the parameter protocol at once.
        payload = bytes(msg.payload)
        seq = (int.from_bytes(payload[0:2], "little") + 1) % 65536  # a reply is request + 1
        nak = bytearray(251)
        nak[0:2] = seq.to_bytes(2, "little")
        nak[2] = payload[2]  # session
        nak[3] = 129
        nak[4] = 1  # data size
        nak[5] = payload[3] if len(payload) > 3 else 0  # req_opcode
        nak[12] = 4
        self._send(link, mavlink.MAVLink_file_transfer_protocol_message(
            0, msg.get_srcSystem(), msg.get_srcComponent(), list(nak)), address)

    def _on_mission_request_list(self, link, address, msg, now) -> None:
        self._send(link, mavlink.MAVLink_mission_count_message(
            msg.get_srcSystem(), msg.get_srcComponent(), 0, getattr(msg, "mission_type", 0)),
            address)

    def _on_ping(self, link, address, msg, now) -> None:
        if msg.target_system == 0:
            self._send(link, mavlink.MAVLink_ping_message(
                msg.time_usec, msg.seq, msg.get_srcSystem(), msg.get_srcComponent()), address)

    def _on_timesync(self, link, address, msg, now) -> None:
        if msg.tc1 == 0:
            self._send(link, mavlink.MAVLink_timesync_message(
                int((now - self.boot_s) * 1e9), msg.ts1), address)

    def _on_set_position_target_local_ned(self, link, address, msg, now) -> None:
        v = self.vehicle
        here = (v.measurement[MEASUREMENT.position_ned_m] if v.measurement is not None
                else np.zeros(3))
        try:
            setpoint = local_setpoint(
                msg.coordinate_frame, msg.type_mask, (msg.x, msg.y, msg.z),
                (msg.vx, msg.vy, msg.vz), (msg.afx, msg.afy, msg.afz), msg.yaw, msg.yaw_rate,
                here, v.heading_rad)
            v.position_setpoint(now, setpoint)
        except RefusedError as exc:
            self._refuse_setpoint(link, address, str(exc))

    def _on_set_position_target_global_int(self, link, address, msg, now) -> None:
        try:
            setpoint = global_setpoint(
                msg.coordinate_frame, msg.type_mask, msg.lat_int, msg.lon_int, msg.alt,
                (msg.vx, msg.vy, msg.vz), (msg.afx, msg.afy, msg.afz), msg.yaw, msg.yaw_rate)
            self.vehicle.position_setpoint(now, setpoint)
        except RefusedError as exc:
            self._refuse_setpoint(link, address, str(exc))

    def _on_set_attitude_target(self, link, address, msg, now) -> None:
        mask = msg.type_mask
        try:
            if mask & BODY_RATES_IGNORE != BODY_RATES_IGNORE:
                raise RefusedError("body-rate setpoints are not supported")
            self.vehicle.attitude_setpoint(
                now, None if mask & ATTITUDE_IGNORE else tuple(msg.q),
                None if mask & THRUST_IGNORE else msg.thrust)
        except RefusedError as exc:
            self._refuse_setpoint(link, address, str(exc))

    def _refuse_setpoint(self, link, address, text: str) -> None:
        # Setpoints stream (20 Hz+): one STATUSTEXT per second at most.
        now = self.clock()
        if now - self._last_refusal_s >= 1.0:
            self._last_refusal_s = now
            self._send(link, mavlink.MAVLink_statustext_message(
                4, f"setpoint refused: {text}".encode()[:50]), address)

    # -- commands ------------------------------------------------------------------------
    def _cmd_arm(self, link, address, p, now):
        if p[0] == 1.0:
            self.vehicle.arm(now)
        elif p[0] == 0.0:
            self.vehicle.disarm(force=p[1] == FORCE_DISARM_MAGIC)
        else:
            raise RefusedError(f"arm param1 must be 0 or 1, got {p[0]:g}")

    def _cmd_takeoff(self, link, address, p, now):
        altitude = p[6]
        if math.isnan(altitude):
            relative = None
        elif self.flavour == "px4":
            relative = altitude - HOME_ALT_AMSL_M  # PX4 reads param7 as AMSL
        else:
            relative = altitude  # ArduPilot reads it above home
        self.vehicle.takeoff(relative)

    def _cmd_land(self, link, address, p, now):
        self.vehicle.land()

    def _cmd_set_mode(self, link, address, p, now):
        base, main, sub = p[0], p[1], p[2]
        if not all(math.isfinite(v) for v in (base, main, sub)):
            raise RefusedError("mode parameters must be finite")
        if not int(base) & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            raise RefusedError("only custom modes are supported")
        number = int(main) if self.flavour == "ardupilot" else px4_custom_mode_from_command(
            main, sub)
        mode = mode_from_custom(self.flavour, number)
        if mode is None:
            raise RefusedError(f"unknown mode {main:g}/{sub:g}")
        self.vehicle.set_mode(mode, now)

    def _cmd_request_message(self, link, address, p, now):
        return [self._message_by_id(int(p[0]))]

    def _cmd_autopilot_capabilities(self, link, address, p, now):
        return [self._autopilot_version()]

    def _cmd_home(self, link, address, p, now):
        return [self._home_position()]

    def _cmd_message_interval(self, link, address, p, now):
        msg_id, interval_us = int(p[0]), p[1]
        if msg_id not in PRODUCIBLE:
            raise RefusedError(f"message {msg_id} is not produced")
        if not math.isfinite(interval_us):
            raise RefusedError("interval must be finite")
        if interval_us == -1:
            link.intervals_s.pop(msg_id, None)
        elif interval_us == 0:
            link.intervals_s[msg_id] = DEFAULT_STREAMS.get(msg_id, 1.0)
        elif interval_us > 0:
            link.intervals_s[msg_id] = max(interval_us * 1e-6, 0.005)
        else:
            raise RefusedError(f"interval {interval_us:g} us is invalid")
        link.next_due_s.pop(msg_id, None)

    def _message_by_id(self, msg_id: int):
        factory = {
            mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION: self._autopilot_version,
            mavlink.MAVLINK_MSG_ID_HOME_POSITION: self._home_position,
        }.get(msg_id)
        if factory is None and msg_id in DEFAULT_STREAMS:
            factory = lambda: self._telemetry(msg_id)  # noqa: E731
        if factory is None:
            raise RefusedError(f"message {msg_id} is not produced")
        return factory()

    # -- telemetry -----------------------------------------------------------------------
    def service(self) -> None:
        """Send what is due and queued; check the link failsafes."""
        now = self.clock()
        self.vehicle.check_links(now)
        shown = (self.vehicle.armed, self.vehicle.mode)
        if shown != self._shown:  # tools read arming and mode off heartbeats
            self._shown = shown
            for link in self.links:
                link.next_due_s[mavlink.MAVLINK_MSG_ID_HEARTBEAT] = now
                link.next_due_s[mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE] = now
        while self.vehicle.messages:
            severity, text = self.vehicle.messages.pop(0)
            self.broadcast(lambda s=severity, t=text: mavlink.MAVLink_statustext_message(
                s, t.encode()))
        for link in self.links:
            for peer in [a for a, p in link.peers.items() if now - p.heard_s > PEER_FORGET_S]:
                del link.peers[peer]
            self._measure_drops(link, now)
            for msg_id, interval in link.intervals_s.items():
                due = link.next_due_s.get(msg_id, now)
                if now >= due:
                    self._send(link, self._telemetry(msg_id))
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
            self.broadcast(lambda: mavlink.MAVLink_statustext_message(
                mavlink.MAV_SEVERITY_WARNING,
                f"{link.name}: {100 * link.drop_rate:.0f}% of datagrams lost "
                f"({c.kernel_drops} dropped, {c.rejected} bad)".encode()[:50]))

    def link_status(self) -> dict[str, dict]:
        """Per link: counters, drop rate and peers (for status records and logs)."""
        for link in self.links:
            link.read_kernel_drops()
        return {link.name: {**link.counters.as_dict(), "drop_rate": round(link.drop_rate, 4),
                            "peers": len(link.peers)} for link in self.links}

    def _telemetry(self, msg_id: int, boot_ms: int | None = None):
        """A telemetry message; ``boot_ms`` defaults to the link clock (the Zenoh mirror
        passes sim time)."""
        v = self.vehicle
        m = v.measurement if v.measurement is not None else np.zeros(12)
        if boot_ms is None:
            boot_ms = int((self.clock() - self.boot_s) * 1000) & 0xFFFFFFFF
        if msg_id == mavlink.MAVLINK_MSG_ID_HEARTBEAT:
            base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | \
                mavlink.MAV_MODE_FLAG_STABILIZE_ENABLED | mavlink.MAV_MODE_FLAG_GUIDED_ENABLED
            if v.armed:
                base |= mavlink.MAV_MODE_FLAG_SAFETY_ARMED
            status = (mavlink.MAV_STATE_CRITICAL if v.failsafe and v.armed else
                      mavlink.MAV_STATE_ACTIVE if v.armed else mavlink.MAV_STATE_STANDBY)
            return mavlink.MAVLink_heartbeat_message(
                mavlink.MAV_TYPE_QUADROTOR, self.mav_autopilot, base,
                custom_mode(self.flavour, v.mode), status, 3)
        if msg_id == mavlink.MAVLINK_MSG_ID_SYS_STATUS:
            health = SENSORS if v.sim_link_ok else 0
            if v.sim_link_ok and (v.armed or v.landed):
                health |= PREARM
            # PX4's meanings: drop_rate_comm in centi-percent (the worst link's, over the
            # last window), errors_comm the datagrams refused (all links).
            drop = max((ln.drop_rate for ln in self.links), default=0.0)
            errors = sum(ln.counters.rejected for ln in self.links)
            return mavlink.MAVLink_sys_status_message(
                SENSORS | PREARM, SENSORS | PREARM, health, 0, 12000, -1, -1,
                min(10_000, round(10_000 * drop)), min(errors, 65535),
                0, 0, 0, 0)
        if msg_id == mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE:
            return mavlink.MAVLink_extended_sys_state_message(
                mavlink.MAV_VTOL_STATE_MC, self._landed_state())
        if msg_id == mavlink.MAVLINK_MSG_ID_ATTITUDE:
            return mavlink.MAVLink_attitude_message(boot_ms, *m[MEASUREMENT.euler_rad],
                                                    *m[MEASUREMENT.euler_rate_rad_s])
        if msg_id == mavlink.MAVLINK_MSG_ID_ATTITUDE_QUATERNION:
            q = _quat_from_euler(m[MEAS_EULER], m[MEAS_EULER + 1], m[MEAS_YAW])
            return mavlink.MAVLink_attitude_quaternion_message(
                boot_ms, *q, *m[MEASUREMENT.euler_rate_rad_s], [0.0, 0.0, 0.0, 0.0])
        if msg_id == mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED:
            return mavlink.MAVLink_local_position_ned_message(
                boot_ms, *m[MEASUREMENT.position_ned_m], *m[MEASUREMENT.velocity_ned_mps])
        if msg_id == mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT:
            lat, lon, alt = geodetic_from_ned(*m[MEASUREMENT.position_ned_m])
            heading = int(math.degrees(m[MEAS_YAW]) % 360.0 * 100) % 36000
            return mavlink.MAVLink_global_position_int_message(
                boot_ms, int(round(lat * 1e7)), int(round(lon * 1e7)), int(round(alt * 1000)),
                int(round(-m[MEAS_Z] * 1000)), *(int(np.clip(round(c * 100), -32768, 32767))
                                            for c in m[MEASUREMENT.velocity_ned_mps]), heading)
        if msg_id == mavlink.MAVLINK_MSG_ID_HOME_POSITION:
            return self._home_position()
        if msg_id == mavlink.MAVLINK_MSG_ID_VFR_HUD:
            speed = float(np.hypot(m[MEAS_VEL], m[MEAS_VEL + 1]))
            heading = int(math.degrees(m[MEAS_YAW]) % 360.0)
            throttle = int(round(100 * float(np.mean(v.last_commands))))
            return mavlink.MAVLink_vfr_hud_message(speed, speed, heading, throttle,
                                                   HOME_ALT_AMSL_M - m[MEAS_Z], -m[MEAS_VZ])
        raise ValueError(f"no telemetry for message {msg_id}")

    def _landed_state(self) -> int:
        v = self.vehicle
        if not v.armed or v.landed:
            return mavlink.MAV_LANDED_STATE_ON_GROUND
        if v.mode == FlightMode.LAND:
            return mavlink.MAV_LANDED_STATE_LANDING
        if v.takeoff_altitude_m is not None:
            return mavlink.MAV_LANDED_STATE_TAKEOFF
        return mavlink.MAV_LANDED_STATE_IN_AIR

    def _home_position(self):
        return mavlink.MAVLink_home_position_message(
            int(HOME_LAT_DEG * 1e7), int(HOME_LON_DEG * 1e7), int(HOME_ALT_AMSL_M * 1000),
            0.0, 0.0, 0.0, [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0)

    def _autopilot_version(self):
        caps = (mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
                | mavlink.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
                | mavlink.MAV_PROTOCOL_CAPABILITY_SET_ATTITUDE_TARGET
                | mavlink.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
                | mavlink.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_GLOBAL_INT
                | mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2)
        return mavlink.MAVLink_autopilot_version_message(
            caps, FIRMWARE_VERSION, 0, 0, 0, [0] * 8, [0] * 8, [0] * 8, 0, 0, 1, [0] * 18)


COMMANDS: dict[int, Callable] = {
    mavlink.MAV_CMD_COMPONENT_ARM_DISARM: GroundStation._cmd_arm,
    mavlink.MAV_CMD_NAV_TAKEOFF: GroundStation._cmd_takeoff,
    mavlink.MAV_CMD_NAV_LAND: GroundStation._cmd_land,
    mavlink.MAV_CMD_DO_SET_MODE: GroundStation._cmd_set_mode,
    mavlink.MAV_CMD_REQUEST_MESSAGE: GroundStation._cmd_request_message,
    mavlink.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES: GroundStation._cmd_autopilot_capabilities,
    mavlink.MAV_CMD_GET_HOME_POSITION: GroundStation._cmd_home,
    mavlink.MAV_CMD_SET_MESSAGE_INTERVAL: GroundStation._cmd_message_interval,
}

assert set(PARAMETER_SPECS) == set(PARAM_INDEX)
