"""What a navigator hands the flight tasks each control period (PX4's position setpoint
triplet, reduced to what this vehicle flies): a setpoint, a speed and a vertical manner."""

from __future__ import annotations

import enum
import math
from typing import NamedTuple

from autopilot.flight_tasks.shaping import Setpoint

# Landing descends towards this far below the ground: it touches down.
LAND_DOWN_M = 0.5


class Vertical(enum.Enum):
    """How a goal moves vertically: the usual limits, the take-off climb
    (MPC_TKO_SPEED) or the landing descent (MPC_LAND_SPEED)."""

    CRUISE = "cruise"
    TAKEOFF = "takeoff"
    LAND = "land"


class Goal(NamedTuple):
    """What to fly this period: a setpoint, a horizontal speed (NaN: the vehicle's
    limit) and how to move vertically."""

    setpoint: Setpoint
    speed_mps: float = math.nan
    vertical: Vertical = Vertical.CRUISE
