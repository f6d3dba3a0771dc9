"""Return to launch (PX4's AUTO.RTL): what the navigator hands the flight tasks while the
vehicle returns (pure: no I/O)."""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field

import numpy as np

from autopilot.flight_tasks.goal import LAND_DOWN_M, Goal, Vertical
from autopilot.flight_tasks.shaping import Setpoint
from autopilot.navigator.mission_runner import heading_to

RETURN_HOME_M = 0.05  # RTL descends once its reference is this close above home


class ReturnPhase(enum.Enum):
    CLIMB = "climb"  # up to RTL_RETURN_ALT (or stay higher)
    RETURN = "return"  # home at that altitude
    DESCEND = "descend"  # down to RTL_DESCEND_ALT
    LAND = "land"


@dataclass
class ReturnToLaunch:
    """PX4's AUTO.RTL: climb to RTL_RETURN_ALT (or stay higher), fly home at that
    altitude facing it, descend to RTL_DESCEND_ALT, land and (the vehicle) disarm.
    Altitudes are above home, which is ``home_ned_m`` in the local frame (the origin
    unless a tool moved home: autopilot/navigator/home.py); the landing is on the ground
    below it."""

    parameters: dict[str, float]
    home_ned_m: np.ndarray = field(default_factory=lambda: np.zeros(3))
    phase: ReturnPhase = ReturnPhase.CLIMB
    _altitude_m: float = 0.0
    _yaw_rad: float = 0.0
    _xy: np.ndarray = field(default_factory=lambda: np.zeros(2))

    def start(self, position_ned_m: np.ndarray, yaw_rad: float) -> None:
        self._altitude_m = max(self._above_home_m(position_ned_m),
                               self.parameters["RTL_RETURN_ALT"])
        self._xy = np.array(position_ned_m[0:2], dtype=float)
        face = heading_to(position_ned_m, self.home_ned_m)
        self._yaw_rad = face if math.isfinite(face) else yaw_rad
        self.phase = ReturnPhase.CLIMB

    def _above_home_m(self, position_ned_m: np.ndarray) -> float:
        return -(float(position_ned_m[2]) - float(self.home_ned_m[2]))

    def _down_m(self, above_home_m: float) -> float:
        return -(above_home_m - float(self.home_ned_m[2]))

    def step(self, position_ned_m: np.ndarray, reference_ned_m: np.ndarray) -> Goal:
        p = self.parameters
        north, east = (float(v) for v in self.home_ned_m[0:2])
        if self.phase is ReturnPhase.CLIMB:
            if abs(self._above_home_m(position_ned_m) - self._altitude_m) <= p["NAV_MC_ALT_RAD"]:
                self.phase = ReturnPhase.RETURN
            else:
                return Goal(Setpoint.hold((*self._xy, self._down_m(self._altitude_m)),
                                          self._yaw_rad))
        if self.phase is ReturnPhase.RETURN:
            ref_off = float(np.hypot(reference_ned_m[0] - north, reference_ned_m[1] - east))
            off = float(np.hypot(position_ned_m[0] - north, position_ned_m[1] - east))
            if ref_off <= RETURN_HOME_M and off <= p["NAV_ACC_RAD"]:
                self.phase = ReturnPhase.DESCEND
            else:
                return Goal(Setpoint.hold((north, east, self._down_m(self._altitude_m)),
                                          self._yaw_rad), p["MPC_XY_CRUISE"])
        descend_to = min(self._altitude_m, p["RTL_DESCEND_ALT"])
        if self.phase is ReturnPhase.DESCEND:
            if self._above_home_m(position_ned_m) - descend_to <= p["NAV_MC_ALT_RAD"]:
                self.phase = ReturnPhase.LAND
            else:
                return Goal(Setpoint.hold((north, east, self._down_m(descend_to)), self._yaw_rad))
        return Goal(Setpoint.hold((north, east, LAND_DOWN_M), self._yaw_rad), math.nan,
                    Vertical.LAND)

    @property
    def landing(self) -> bool:
        return self.phase is ReturnPhase.LAND

