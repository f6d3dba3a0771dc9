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
    altitude facing it, descend to RTL_DESCEND_ALT, land and (the vehicle) disarm. Home
    is the local origin."""

    parameters: dict[str, float]
    phase: ReturnPhase = ReturnPhase.CLIMB
    _altitude_m: float = 0.0
    _yaw_rad: float = 0.0
    _xy: np.ndarray = field(default_factory=lambda: np.zeros(2))

    def start(self, position_ned_m: np.ndarray, yaw_rad: float) -> None:
        self._altitude_m = max(-float(position_ned_m[2]), self.parameters["RTL_RETURN_ALT"])
        self._xy = np.array(position_ned_m[0:2], dtype=float)
        face = heading_to(position_ned_m, np.zeros(3))
        self._yaw_rad = face if math.isfinite(face) else yaw_rad
        self.phase = ReturnPhase.CLIMB

    def step(self, position_ned_m: np.ndarray, reference_ned_m: np.ndarray) -> Goal:
        p = self.parameters
        if self.phase is ReturnPhase.CLIMB:
            if abs(-position_ned_m[2] - self._altitude_m) <= p["NAV_MC_ALT_RAD"]:
                self.phase = ReturnPhase.RETURN
            else:
                return Goal(Setpoint.hold((*self._xy, -self._altitude_m), self._yaw_rad))
        if self.phase is ReturnPhase.RETURN:
            if float(np.hypot(*reference_ned_m[0:2])) <= RETURN_HOME_M and float(
                    np.hypot(*position_ned_m[0:2])) <= p["NAV_ACC_RAD"]:
                self.phase = ReturnPhase.DESCEND
            else:
                return Goal(Setpoint.hold((0.0, 0.0, -self._altitude_m), self._yaw_rad),
                            p["MPC_XY_CRUISE"])
        descend_to = min(self._altitude_m, p["RTL_DESCEND_ALT"])
        if self.phase is ReturnPhase.DESCEND:
            if -position_ned_m[2] - descend_to <= p["NAV_MC_ALT_RAD"]:
                self.phase = ReturnPhase.LAND
            else:
                return Goal(Setpoint.hold((0.0, 0.0, -descend_to), self._yaw_rad))
        return Goal(Setpoint.hold((0.0, 0.0, LAND_DOWN_M), self._yaw_rad), math.nan, Vertical.LAND)

    @property
    def landing(self) -> bool:
        return self.phase is ReturnPhase.LAND

