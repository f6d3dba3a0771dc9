"""HOLD (PX4's AUTO.LOITER): hold where the mode began, or fly to where a go-to
(MAV_CMD_DO_REPOSITION) asked, at its speed, and hold there."""

from __future__ import annotations

import math

import numpy as np

from autopilot.flight_tasks.shaping import Setpoint
from autopilot.flight_tasks.task import BaseTask, TaskOutput
from contracts.modes import FlightMode


class HoldTask(BaseTask):
    speed_mps = math.nan  # a go-to's speed; NaN: the vehicle's limit

    def activate(self, previous: FlightMode, armed: bool) -> None:
        self.speed_mps = math.nan
        self.state.hold_here()

    def go_to(self, target_ned_m: np.ndarray, yaw_rad: float, speed_mps: float) -> None:
        self.state.setpoint = Setpoint.hold(target_ned_m, yaw_rad)
        self.speed_mps = speed_mps

    def update(self) -> TaskOutput:
        return self.state.translate(self.speed_mps)
