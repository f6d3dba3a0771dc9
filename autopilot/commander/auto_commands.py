"""The commands that say where an automatic mode flies: start the mission (PX4's
AUTO.MISSION), go to a position and hold there (AUTO.LOITER), change the speed.

They act on the navigator and on the tasks that fly HOLD and MISSION; what they need of
the rest of the vehicle (arming, mode, switching mode) they read through
:class:`AutoVehicle`, which the commander provides.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from autopilot.flight_tasks.hold import HoldTask
from autopilot.flight_tasks.mission import MissionTask
from autopilot.flight_tasks.task import TaskState
from autopilot.navigator.navigator import Navigator
from autopilot.refusal import RefusedError
from contracts.modes import FlightMode


class AutoVehicle(Protocol):
    """What the automatic modes' commands read of the vehicle and ask of it."""

    armed: bool
    mode: FlightMode

    @property
    def landed(self) -> bool: ...

    def set_mode(self, mode: FlightMode, link_t_s: float) -> None:
        """Enter ``mode`` as a tool asks for it (its needs checked first)."""
        ...


@dataclass(eq=False)
class AutoCommands:
    """MAV_CMD_MISSION_START, MAV_CMD_DO_REPOSITION and MAV_CMD_DO_CHANGE_SPEED."""

    vehicle: AutoVehicle
    navigator: Navigator
    hold: HoldTask
    mission: MissionTask
    state: TaskState
    say: Callable[[str], None]

    def start_mission(self, first_seq: int, link_t_s: float) -> None:
        """MAV_CMD_MISSION_START: fly the mission from item ``first_seq``."""
        self.navigator.select(first_seq)
        if self.vehicle.mode == FlightMode.MISSION:
            self.mission.restart()
        else:
            self.vehicle.set_mode(FlightMode.MISSION, link_t_s)

    def reposition(self, target_ned_m: np.ndarray, yaw_rad: float, speed_mps: float) -> None:
        """MAV_CMD_DO_REPOSITION: fly to a position (NaN: keep that coordinate) and hold
        there, in HOLD (PX4's AUTO.LOITER)."""
        v = self.vehicle
        if not v.armed or v.landed:
            raise RefusedError("go-to denied: not in the air", temporary=True)
        if any(math.isinf(x) for x in (*target_ned_m, yaw_rad, speed_mps)):
            raise RefusedError("go-to values must be finite or NaN")
        if math.isfinite(speed_mps) and \
                not 0 < speed_mps <= self.state.parameters["MPC_XY_VEL_MAX"]:
            speed_mps = math.nan  # -1 (the default speed) or beyond the limit
        self.hold.reposition(target_ned_m, yaw_rad, speed_mps, v.mode is FlightMode.HOLD)

    def change_speed(self, speed_mps: float) -> None:
        """MAV_CMD_DO_CHANGE_SPEED in flight: the mission's speed and a go-to's (-1: no
        change)."""
        if not self.navigator.change_speed(speed_mps):
            return
        if self.vehicle.mode == FlightMode.HOLD:
            self.hold.speed_mps = speed_mps
        self.say(f"speed {speed_mps:.1f} m/s")
