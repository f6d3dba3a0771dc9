"""The autopilot's link to the simulator: a TCP client speaking PX4's simulator protocol.

It connects (and reconnects while the simulator is away), sends the simulator a
heartbeat, and turns the state messages it reads into typed samples: the simulator's
truth (HIL_STATE_QUATERNION or ODOMETRY) as a measurement, HIL_SENSOR as an IMU reading
and HIL_GPS as a fix. What the samples are used for is not its business: the process
feeds the sensor samples to its estimator (``navigation.py``).
"""

from __future__ import annotations

import math
import socket
from typing import NamedTuple

import numpy as np

from autopilot.estimation.estimator import GpsFix
from contracts.frames import Home
from contracts.mavlink import (
    AUTOPILOT_COMPID,
    AUTOPILOT_SYSID,
    HIL_FLAG_LOCKSTEP,
    HIL_MODE_ARMED,
    STATE_SOURCES,
    LinkDataError,
    actuator_message,
    fix_from_hil_gps,
    home_from_message,
    imu_from_hil_sensor,
    mavlink,
    measurement_from_hil_state,
    measurement_from_odometry,
    new_mavlink,
    split_frames,
)
from contracts.paced_loop import lockstep_waits
from contracts.sim_readings import (
    GPS_FIX_TYPE,
    GPS_POSITION,
    GPS_SATELLITES,
    GPS_VELOCITY,
    IMU,
    IMU_ACCEL,
    IMU_BARO_ALT,
    IMU_GYRO,
    IMU_HAS_MAG,
    IMU_MAG,
    TRUTH,
    FrameReader,
)
from contracts.sim_samples import ACTUATORS_BYTES, pack_actuators
from contracts.vectors import MEASUREMENT

# The messages a home can come from, read for it whatever the vehicle flies on.
HOME_IDS = frozenset((mavlink.MAVLINK_MSG_ID_HIL_STATE_QUATERNION, mavlink.MAVLINK_MSG_ID_HIL_GPS))
# A simulator that sends no HIL_STATE_QUATERNION gives home from its first GPS fix, once
# fixes have come for this long without one (a fix carries the receiver's error, typically
# decimetres, which the vehicle's idea of where it stands inherits).
HOME_FROM_GPS_AFTER_US = 500_000
SIM_HEARTBEAT_S = 1.0  # to the simulator, from the connection on (jMAVSim waits for one)
# Connection attempts: every 20 ms at first, backing off to every 0.5 s. A scenario run
# starts both processes at once and the simulator listens a few hundred milliseconds
# later; at a flat 0.5 s the autopilot met it up to half a second late.
RECONNECT_FIRST_S = 0.02
RECONNECT_S = 0.5


class TruthReading(NamedTuple):
    """The simulator's truth: the measurement the controller flies on."""

    time_us: int
    measurement: np.ndarray


class ImuReading(NamedTuple):
    """HIL_SENSOR: gyro and specific force FRD, baro altitude AMSL [m] (NaN: not fresh),
    magnetometer FRD [gauss] (None: not fresh)."""

    time_us: int
    gyro: np.ndarray
    accel: np.ndarray
    baro_alt_amsl_m: float
    mag: np.ndarray | None


class GpsReading(NamedTuple):
    """HIL_GPS: a fix, at the time it was received."""

    time_us: int
    fix: GpsFix


LinkReading = TruthReading | ImuReading | GpsReading


def _reading(kind: int, time_us: int, row: np.ndarray) -> tuple[str, LinkReading]:
    """(message type, reading) of a row the compiled reader decoded."""
    if kind == TRUTH:
        return "ODOMETRY", TruthReading(time_us, row[:MEASUREMENT.size].copy())
    if kind == IMU:
        mag = row[IMU_MAG:IMU_MAG + 3].copy() if row[IMU_HAS_MAG] else None
        return "HIL_SENSOR", ImuReading(time_us, row[IMU_GYRO:IMU_GYRO + 3].copy(),
                                        row[IMU_ACCEL:IMU_ACCEL + 3].copy(),
                                        float(row[IMU_BARO_ALT]), mag)
    return "HIL_GPS", GpsReading(time_us, GpsFix(
        row[GPS_POSITION:GPS_POSITION + 3].copy(), row[GPS_VELOCITY:GPS_VELOCITY + 3].copy(),
        int(row[GPS_FIX_TYPE]), int(row[GPS_SATELLITES])))


class SimLink:
    """TCP client of the simulator; reconnects while the simulator is away.

    ``wait_s``: 0 (real time) reads without waiting, the loop's selector says when there
    is data; above 0 (lockstep) ``read`` itself waits up to that long for the next
    sample, with no selector round trip (5 us a cycle in Python). The lockstep loop
    serves its ground links after a read when they are due: every 5 to 10 ms while the
    simulator is silent."""

    def __init__(self, host: str, port: int, source: str,
                 sysid: int = AUTOPILOT_SYSID, home: Home | None = None,
                 wait_s: float = 0.0) -> None:
        self.address = (host, port)
        self._home_values = np.zeros(3)  # home as the compiled reader takes it
        self.wait_s = wait_s
        # The local frame's origin: given, or the simulator's first position (as PX4's
        # simulator_mavlink takes its reference); None until then.
        self.home = home
        self.home_source = "given" if home is not None else None
        self._first_fix: tuple[int, Home] | None = None  # (time_usec, home) of HIL_GPS
        self.sock: socket.socket | None = None
        self.source = source
        self.source_types = STATE_SOURCES[source]
        self.source_ids = frozenset(getattr(mavlink, f"MAVLINK_MSG_ID_{t}")
                                    for t in self.source_types) | {-1}
        # Once ODOMETRY flows (auto), HIL_STATE_QUATERNION is not even parsed.
        self._ids_with_odometry = self.source_ids - {
            mavlink.MAVLINK_MSG_ID_HIL_STATE_QUATERNION}
        self._pending = b""
        self.odometry_seen = False  # auto: once ODOMETRY arrives, HIL_STATE is not used
        self.next_heartbeat_s = math.inf
        self.sysid = sysid
        self.mav = new_mavlink(sysid, AUTOPILOT_COMPID)
        self.next_attempt_s = 0.0
        self._retry_s = RECONNECT_FIRST_S
        self.bad_messages = 0
        self.last_bad: str | None = None
        # The wanted ids (before and once ODOMETRY flows), and the reader.
        self._wanted = {seen: np.array(sorted(ids - {-1}), dtype=np.int64) for seen, ids in (
            (False, self.source_ids), (True, self._ids_with_odometry))}
        self._reader = FrameReader(_reading)
        self._answer = np.empty(ACTUATORS_BYTES, dtype=np.uint8)  # the answer's frame

    @property
    def home(self) -> Home | None:
        return self._home

    @home.setter
    def home(self, home: Home | None) -> None:
        self._home = home
        if home is not None:
            self._home_values[:] = home

    def twin_at(self, home: Home) -> SimLink:
        """A link that reads as this one does (its state source), at ``home``, with its own
        parser and buffers, and no socket: for warming the compiled code up."""
        return SimLink(*self.address, self.source, self.sysid, home, self.wait_s)

    def connect(self, now: float) -> bool:
        """Try to connect (every RECONNECT_FIRST_S at first, backing off to RECONNECT_S);
        True when a connection is new."""
        if self.sock is not None or now < self.next_attempt_s:
            return False
        self.next_attempt_s = now + self._retry_s
        try:
            sock = socket.create_connection(self.address, timeout=0.2)
        except OSError:
            self._retry_s = min(RECONNECT_S, 1.5 * self._retry_s)
            return False
        self._retry_s = RECONNECT_FIRST_S  # after this one is lost: quickly again
        self.next_attempt_s = now + RECONNECT_FIRST_S
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        if self.wait_s > 0.0:
            lockstep_waits(sock, self.wait_s)
        else:
            sock.setblocking(False)
        self.sock = sock
        self.mav = new_mavlink(self.sysid, AUTOPILOT_COMPID)
        self._pending = b""
        self.odometry_seen = False
        self._first_fix = None  # a fix from another simulator's session gives no home
        self.next_heartbeat_s = now  # at once: some simulators wait for it
        return True

    def heartbeat_due(self, now: float) -> bool:
        """Send the simulator a HEARTBEAT on connecting and every SIM_HEARTBEAT_S."""
        if self.sock is None or now < self.next_heartbeat_s:
            return False
        self.next_heartbeat_s = max(self.next_heartbeat_s + SIM_HEARTBEAT_S, now)
        msg = mavlink.MAVLink_heartbeat_message(
            mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_PX4, 0, 0,
            mavlink.MAV_STATE_ACTIVE, 3)
        return self.send(msg.pack(self.mav))

    def decode(self, msg: mavlink.MAVLink_message, kind: str | None = None
               ) -> LinkReading | None:
        """The sample of a state message (raises LinkDataError on bad data); None for a
        position before home is known (a HIL_GPS without a fix). ``kind``: its type, when
        the caller has it."""
        kind = kind or msg.get_type()
        if kind == "ODOMETRY":
            return TruthReading(msg.time_usec, measurement_from_odometry(msg))
        if self.home is None and kind != "HIL_SENSOR":
            return None
        if kind == "HIL_STATE_QUATERNION":
            return TruthReading(msg.time_usec, measurement_from_hil_state(msg, self.home))
        if kind == "HIL_GPS":
            position, velocity, fix_type, satellites = fix_from_hil_gps(msg, self.home)
            return GpsReading(msg.time_usec, GpsFix(position, velocity, fix_type, satellites))
        gyro, accel, baro_alt, mag = imu_from_hil_sensor(msg)
        return ImuReading(msg.time_usec, gyro, accel, baro_alt, mag)

    def _take_home(self, msgs: list[mavlink.MAVLink_message]) -> None:
        """Home from the first HIL_STATE_QUATERNION (the simulator's truth, exact); from
        the first 3D GPS fix only when no HIL_STATE_QUATERNION has come after
        HOME_FROM_GPS_AFTER_US of fixes."""
        for msg in msgs:
            try:
                home = home_from_message(msg)
            except LinkDataError as exc:
                self.bad_messages += 1
                self.last_bad = str(exc)
                continue
            if home is None:
                continue
            if msg.get_type() == "HIL_STATE_QUATERNION":
                self.home, self.home_source = home, "from the simulator's HIL_STATE_QUATERNION"
                return
            if self._first_fix is None:
                self._first_fix = (msg.time_usec, home)
            elif msg.time_usec - self._first_fix[0] >= HOME_FROM_GPS_AFTER_US:
                self.home = self._first_fix[1]
                self.home_source = "from the simulator's first GPS fix (no HIL_STATE_QUATERNION)"
                return

    def close(self) -> None:
        if self.sock is not None:
            self.sock.close()
            self.sock = None

    def read(self) -> list[LinkReading] | None:
        """The samples now available (with ``wait_s``, the next within it), in the order
        sent (a refused message is counted in ``bad_messages`` and left out); None when
        the link closed."""
        try:
            data = self.sock.recv(262144)
        except (BlockingIOError, InterruptedError, TimeoutError):
            return []
        except OSError:
            return None
        if not data:
            return None
        return self.readings_of(self._pending + data)

    def readings_of(self, data: bytes) -> list[LinkReading]:
        """The samples in ``data`` (what came after the last frame cut off), in the order
        sent; a frame cut off at its end waits for the next read."""
        if self.home is None or self.mav.signing.secret_key is not None:
            # Until home is known, and on a link that checks signatures: every frame it
            # wants through pymavlink.
            frames, self._pending = split_frames(data)
            ids = self.source_ids | HOME_IDS
            parsed = self.mav.parse_buffer(b"".join(f for i, f in frames if i in ids)) or []
            self._take_home(parsed)
            return self._samples([(m.get_type(), m) for m in parsed])
        # The frames read in compiled code (contracts/sim_readings.py): decoded where they
        # are plain, to pymavlink and the decoders below where not.
        items, self._pending = self._reader.read(data, self._wanted[self.odometry_seen],
                                                 self._home_values, self.mav)
        return self._samples([item if isinstance(item, tuple) else (item.get_type(), item)
                              for item in items])

    def _samples(self, entries: list[tuple[str, object]]) -> list[LinkReading]:
        """The readings of (type, message or decoded reading) in order: the state source's
        messages decoded (a refusal counted), HIL_STATE_QUATERNION skipped once ODOMETRY
        flows."""
        types = self.source_types
        msgs = [(kind, m) for kind, m in entries if kind in types]
        if not self.odometry_seen and any(kind == "ODOMETRY" for kind, _ in msgs):
            self.odometry_seen = True
        samples = []
        for kind, msg in msgs:
            if self.odometry_seen and kind == "HIL_STATE_QUATERNION":
                continue  # the same sample, from the message the controller prefers
            if isinstance(msg, (TruthReading, ImuReading, GpsReading)):
                samples.append(msg)
                continue
            try:
                sample = self.decode(msg, kind)
            except LinkDataError as exc:
                self.bad_messages += 1
                self.last_bad = str(exc)
                continue
            if sample is not None:
                samples.append(sample)
        return samples

    def actuators_frame(self, time_us: int, commands: np.ndarray, armed: bool,
                        lockstep: bool) -> bytes:
        """The answer to the sample at ``time_us``: HIL_ACTUATOR_CONTROLS of ``commands``
        (``pack_actuators``; by pymavlink on a link that signs)."""
        mav = self.mav
        if mav.signing.sign_outgoing:
            return actuator_message(time_us, commands, armed, lockstep).pack(mav)
        end = pack_actuators(self._answer, mav.seq, mav.srcSystem, mav.srcComponent, time_us,
                             commands, HIL_MODE_ARMED if armed else 0,
                             HIL_FLAG_LOCKSTEP if lockstep else 0)
        return self._answer[:end].tobytes()

    def send(self, data: bytes) -> bool:
        """Whether ``data`` went out (False: the link is lost, or was already)."""
        if self.sock is None:
            return False
        try:
            self.sock.sendall(data)
            return True
        except OSError:
            return False
