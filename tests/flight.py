"""The vehicle's logic and controller flying the plant in one process, on sim time.

What a ground tool does (arm, take off, stream setpoints) is called directly on
:class:`autopilot.commander.commander.Commander`, with sim time as the link clock, so a flight is
deterministic and takes a fraction of a second of wall time. Processes and real tools
are tested in test_mavsdk_flights.py; this is for the logic and the numbers.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from autopilot.commander.commander import Commander
from autopilot.control.factory import load_models, make_controller
from autopilot.flight_tasks.shaping import Setpoint
from contracts.airframe import PAPER, Airframe
from sitl.plant import Plant

_MODELS = None


def shipped_models():
    global _MODELS
    if _MODELS is None:
        _MODELS = load_models(None)
    return _MODELS


class Flight:
    """A vehicle on the ground at the origin, facing ``yaw_rad``; ``log`` holds one row of
    [t, measurement (12), reference (18)] per control period."""

    def __init__(self, controller: str = "ivfc", plant: str = "rigid-body",
                 airframe: Airframe = PAPER, period_s: float = 0.01, yaw_rad: float = 0.0,
                 parameters: dict[str, float] | None = None, flavour: str = "px4") -> None:
        models = shipped_models() if controller in ("ivfc", "t1fc") else None
        self.plant = Plant(airframe, plant, 0.001, euler_rad=(0.0, 0.0, yaw_rad),
                           ground_contact=True)
        self.vehicle = Commander(
            lambda p: make_controller(controller, airframe, period_s, models, p), period_s,
            parameters, flavour=flavour)
        self.period_s = period_s
        self.steps = 0
        self.rows: list[np.ndarray] = []

    @property
    def t_s(self) -> float:
        return self.steps * self.period_s

    def run(self, duration_s: float, each_period: Callable[[float], None] | None = None,
            samples_arrive: bool = False) -> None:
        """Fly ``duration_s``; ``each_period(t)`` runs before each control step (a tool
        streaming setpoints). ``samples_arrive``: as the real-time loop does, each sample
        is taken as it arrives, then again by the control step."""
        for _ in range(round(duration_s / self.period_s)):
            t = self.t_s
            if each_period is not None:
                each_period(t)
            self.vehicle.check_links(t)
            measurement = self.plant.true_measurement()
            if samples_arrive:
                self.vehicle.sample(t, measurement)
            commands = self.vehicle.step(t, measurement)
            self.rows.append(np.concatenate(([t], measurement, self.vehicle.flight.last_ref)))
            self.plant.set_motor_commands(commands)
            self.plant.advance(self.period_s)
            self.steps += 1

    def lose(self, periods: int, samples_arrive: bool = False) -> None:
        """``periods`` control periods with no control step, the last commands holding:
        a real-time step that came too late (the sim time runs on). ``samples_arrive``:
        the samples of those periods are taken all the same, as the real-time loop takes
        each sample as it arrives (autopilot/process/loop.py) and steps on the newest."""
        for _ in range(periods):
            if samples_arrive:
                self.vehicle.sample(self.t_s, self.plant.true_measurement())
            self.plant.advance(self.period_s)
            self.steps += 1

    def take_off(self, altitude_m: float = 2.5) -> None:
        self.run(0.05)  # the first samples: the simulator link comes up
        takeoff_mode = self.vehicle.personality.takeoff_mode  # Copter: GUIDED
        if takeoff_mode is not None:
            self.vehicle.set_mode(takeoff_mode, self.t_s)
        self.vehicle.arm(self.t_s)
        self.vehicle.takeoff(altitude_m)
        self.run(8.0)
        assert self.vehicle.takeoff_altitude_m is None, "take-off did not complete"

    def stream(self, setpoint: Setpoint, duration_s: float, rate_hz: float = 20.0) -> None:
        """Stream one setpoint at ``rate_hz`` (as MAVSDK does) for ``duration_s``."""
        every = round(1.0 / (rate_hz * self.period_s))
        start = self.steps

        def send(t: float) -> None:
            if (self.steps - start) % every == 0:
                self.vehicle.inputs.position_setpoint(t, setpoint)
        self.run(duration_s, send)

    def start_offboard(self, setpoint: Setpoint) -> None:
        from contracts.modes import FlightMode

        self.stream(setpoint, 0.2)
        self.vehicle.set_mode(FlightMode.OFFBOARD, self.t_s)

    @property
    def log(self) -> np.ndarray:
        return np.array(self.rows)

    def since(self, t_s: float) -> np.ndarray:
        log = self.log
        return log[log[:, 0] >= t_s - 1e-9]


def yaw_travel_rad(yaw: np.ndarray) -> float:
    """Total angle turned through (the vehicle spinning round counts every turn)."""
    return float(np.sum(np.abs(np.diff(np.unwrap(yaw)))))


def position_setpoint(north: float, east: float, down: float, yaw_deg: float | None = None,
                      velocity=None) -> Setpoint:
    return Setpoint(np.array([north, east, down], dtype=float),
                    np.array(velocity if velocity is not None else (math.nan,) * 3,
                             dtype=float),
                    yaw_rad=math.nan if yaw_deg is None else math.radians(yaw_deg))


def velocity_setpoint(north: float, east: float, down: float,
                      yaw_deg: float | None = None) -> Setpoint:
    return Setpoint(velocity_ned_mps=np.array([north, east, down], dtype=float),
                    yaw_rad=math.nan if yaw_deg is None else math.radians(yaw_deg))


def mission_item(seq: int, north: float, east: float, altitude_m: float,
                 command: int | None = None, params=(0.0, 0.0, 0.0, math.nan)):
    """A MISSION_ITEM_INT-style item at ``north``, ``east`` [m] from home, ``altitude_m``
    above home (GLOBAL_RELATIVE_ALT_INT, as QGroundControl and MAVSDK send them)."""
    from autopilot.navigator.mission_store import MissionItem
    from contracts.frames import DEFAULT_HOME
    from contracts.mavlink import mavlink

    lat, lon, _ = DEFAULT_HOME.geodetic_from_ned(north, east, 0.0)
    return MissionItem(seq, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
                       mavlink.MAV_CMD_NAV_WAYPOINT if command is None else command, 0, 1,
                       tuple(float(p) for p in params), round(lat * 1e7), round(lon * 1e7),
                       altitude_m)


def do_item(seq: int, command: int, params) -> object:
    from autopilot.navigator.mission_store import MissionItem
    from contracts.mavlink import mavlink

    return MissionItem(seq, mavlink.MAV_FRAME_MISSION, command, 0, 1,
                       tuple(float(p) for p in params), 0, 0, 0.0)
