"""A small simulator of PX4's simulator protocol, for testing the autopilot against a
simulator that is not ours.

Written from PX4's documentation of the protocol (the simulator listens on TCP, the
flight stack connects; MAVLink 2; HIL_SENSOR carries the IMU, magnetometer and
barometer, HIL_STATE_QUATERNION the state; HIL_ACTUATOR_CONTROLS comes back, controls[i]
driving motor i+1; in lockstep the simulator waits for the actuator message before it
steps), and behaving like jMAVSim in the ways that matter here: it waits for the flight
stack's first HEARTBEAT before it sends anything, its clock starts at an arbitrary
origin, and it sends no ODOMETRY. Nothing here comes from ``sitl/``: its own rigid body,
its own rotor geometry table, its own geodetic conversion.
"""

from __future__ import annotations

import collections
import math
import socket
import threading
from dataclasses import dataclass, field

import numpy as np
from pymavlink.dialects.v20 import common as mavlink

G = 9.81
HOME = (47.397742, 8.545594, 488.0)  # PX4's default SITL home
EARTH_RADIUS_M = 6_378_137.0
MAG_NED_GAUSS = np.array([0.21, 0.01, 0.42])


@dataclass(frozen=True)
class Rotor:
    position_frd_m: tuple[float, float, float]
    spin: int  # +1 clockwise seen from above (angular velocity along +z_b), -1 ccw


@dataclass(frozen=True)
class Vehicle:
    mass_kg: float
    inertia_kgm2: tuple[float, float, float]  # diagonal, body FRD
    thrust_coeff: float  # T = k W^2
    moment_coeff: float  # reaction torque km W^2
    max_rad_s: float  # motor command c -> rotor speed c * max_rad_s
    rotors: tuple[Rotor, ...]


# PX4's quad X in its motor order (PX4's airframe reference: 1 front right ccw, 2 rear
# left ccw, 3 front left cw, 4 rear right cw), with the numbers of PX4's x500 simulation
# model: 2 kg, motor constant 8.54858e-6, moment constant 0.016, 1000 rad/s.
QUAD_X = Vehicle(2.0, (0.0217, 0.0217, 0.040), 8.54858e-6, 0.016 * 8.54858e-6, 1000.0, (
    Rotor((0.175, 0.175, 0.0), -1), Rotor((-0.175, -0.175, 0.0), -1),
    Rotor((0.175, -0.175, 0.0), +1), Rotor((-0.175, 0.175, 0.0), +1)))


def _rotation(q: np.ndarray) -> np.ndarray:
    w, x, y, z = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


@dataclass
class Body:
    position_ned: np.ndarray = field(default_factory=lambda: np.zeros(3))
    velocity_ned: np.ndarray = field(default_factory=lambda: np.zeros(3))
    quaternion: np.ndarray = field(default_factory=lambda: np.array([1.0, 0, 0, 0]))
    rates_frd: np.ndarray = field(default_factory=lambda: np.zeros(3))
    accel_ned: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def step(self, v: Vehicle, rotor_rad_s: np.ndarray, dt: float) -> None:
        """Semi-implicit Euler: thrust along -z_b at each rotor, torques r x F plus each
        rotor's drag reaction -spin km W^2 about z_b; the ground at z = 0 holds it."""
        thrust = v.thrust_coeff * rotor_rad_s**2
        torque = np.zeros(3)
        for rotor, t, w in zip(v.rotors, thrust, rotor_rad_s, strict=True):
            torque += np.cross(rotor.position_frd_m, (0.0, 0.0, -t))
            torque[2] += -rotor.spin * v.moment_coeff * w * w
        inertia = np.array(v.inertia_kgm2)
        omega = self.rates_frd
        omega_dot = (torque - np.cross(omega, inertia * omega)) / inertia
        rot = _rotation(self.quaternion)
        accel = rot @ np.array([0.0, 0.0, -thrust.sum() / v.mass_kg]) + (0.0, 0.0, G)
        self.velocity_ned = self.velocity_ned + accel * dt
        self.rates_frd = omega + omega_dot * dt
        self.position_ned = self.position_ned + self.velocity_ned * dt
        p, q, r = self.rates_frd
        w, x, y, z = self.quaternion
        q_dot = 0.5 * np.array([-x * p - y * q - z * r, w * p + y * r - z * q,
                                w * q - x * r + z * p, w * r + x * q - y * p])
        self.quaternion = self.quaternion + q_dot * dt
        self.quaternion /= np.linalg.norm(self.quaternion)
        if self.position_ned[2] >= 0.0 and self.velocity_ned[2] >= 0.0:  # on the ground
            self.position_ned[2] = 0.0
            self.velocity_ned[:] = 0.0
            self.rates_frd[:] = 0.0
            accel = np.zeros(3)
        self.accel_ned = accel


def _geodetic(position_ned: np.ndarray) -> tuple[float, float, float]:
    lat0, lon0, alt0 = HOME
    n, e, d = position_ned
    return (lat0 + math.degrees(n / EARTH_RADIUS_M),
            lon0 + math.degrees(e / (EARTH_RADIUS_M * math.cos(math.radians(lat0)))),
            alt0 - d)


class Px4ProtocolSim(threading.Thread):
    """Listens on ``port``; after the flight stack's first HEARTBEAT, sends HIL_SENSOR and
    HIL_STATE_QUATERNION every sample and waits for HIL_ACTUATOR_CONTROLS (lockstep)."""

    def __init__(self, port: int, vehicle: Vehicle = QUAD_X, rate_hz: float = 250.0,
                 start_time_us: int = 7_123_456_789, substeps: int = 4) -> None:
        super().__init__(daemon=True)
        self.vehicle = vehicle
        self.period_us = round(1e6 / rate_hz)
        self.time_us = start_time_us
        self.substeps = substeps
        self.body = Body()
        self.rotor_rad_s = np.zeros(len(vehicle.rotors))
        self.server = socket.create_server(("127.0.0.1", port))
        self.mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=51)
        self.heartbeat_first = False  # the flight stack spoke before our first sample
        self.samples = 0
        self.answers = 0
        self.other_messages: set[str] = set()
        self._pending: collections.deque = collections.deque()
        self.stop_event = threading.Event()
        self.error: str | None = None

    def run(self) -> None:
        try:
            conn, _ = self.server.accept()
            conn.settimeout(10.0)
            self._wait_for_heartbeat(conn)
            while not self.stop_event.is_set():
                conn.sendall(self._sample())
                self.samples += 1
                self._apply(self._wait_for_actuators(conn))
                dt = self.period_us / 1e6 / self.substeps
                for _ in range(self.substeps):
                    self.body.step(self.vehicle, self.rotor_rad_s, dt)
                self.time_us += self.period_us
        except (OSError, TimeoutError) as exc:
            if not self.stop_event.is_set():
                self.error = f"{type(exc).__name__}: {exc}"
        finally:
            self.server.close()

    def _messages(self, conn: socket.socket):
        """Messages in arrival order; those parsed but not yet taken wait in ``_pending``
        (a HEARTBEAT read in the same chunk as an answer is not lost with the generator)."""
        while True:
            while self._pending:
                yield self._pending.popleft()
            data = conn.recv(4096)
            if not data:
                raise OSError("the flight stack closed the connection")
            self._pending.extend(self.mav.parse_buffer(data) or [])

    def _wait_for_heartbeat(self, conn: socket.socket) -> None:
        for msg in self._messages(conn):
            if msg.get_type() == "HEARTBEAT":
                self.heartbeat_first = True
                return

    def _wait_for_actuators(self, conn: socket.socket):
        for msg in self._messages(conn):
            if msg.get_type() == "HIL_ACTUATOR_CONTROLS":
                self.answers += 1
                return msg
            self.other_messages.add(msg.get_type())

    def _apply(self, msg) -> None:
        armed = bool(msg.mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)
        commands = np.clip(np.array(msg.controls[:len(self.rotor_rad_s)]), 0.0, 1.0)
        self.rotor_rad_s = commands * self.vehicle.max_rad_s if armed else np.zeros_like(
            self.rotor_rad_s)

    def _sample(self) -> bytes:
        b = self.body
        rot = _rotation(b.quaternion)
        specific_force = rot.T @ (b.accel_ned - (0.0, 0.0, G))
        mag = rot.T @ MAG_NED_GAUSS
        lat, lon, alt = _geodetic(b.position_ned)
        pressure_hpa = 1013.25 * (1 - 2.25577e-5 * alt) ** 5.25588
        p, q, r = (float(v) for v in b.rates_frd)
        sensor = mavlink.MAVLink_hil_sensor_message(
            self.time_us, *specific_force, p, q, r, *mag, pressure_hpa, 0.0, alt, 15.0,
            0x1FFF, 0)
        vn, ve, vd = (int(round(v * 100)) for v in b.velocity_ned)
        accel_mg = (int(round(a * 1000 / G)) for a in specific_force)
        state = mavlink.MAVLink_hil_state_quaternion_message(
            self.time_us, [float(v) for v in b.quaternion], p, q, r, int(round(lat * 1e7)),
            int(round(lon * 1e7)), int(round(alt * 1000)), vn, ve, vd, 0, 0, *accel_mg)
        return sensor.pack(self.mav) + state.pack(self.mav)

    def stop(self) -> None:
        self.stop_event.set()
