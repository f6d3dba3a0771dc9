"""HOLD (PX4's AUTO.LOITER): hold where the mode began, or fly to where a go-to
(MAV_CMD_DO_REPOSITION) asked, at its speed, and hold there. As ArduPilot's LOITER with
RC sticks (``loiter_sticks``), a deflected stick flies as POSCTL does and a stick back at
centre holds where the vehicle can stop."""

from __future__ import annotations

import math

import numpy as np

from autopilot.flight_tasks.shaping import Setpoint
from autopilot.flight_tasks.sticks import position_control
from autopilot.flight_tasks.task import BaseTask, TaskOutput
from autopilot.refusal import RefusedError
from contracts.modes import FlightMode


class HoldTask(BaseTask):
    speed_mps = math.nan  # a go-to's speed; NaN: the vehicle's limit
    _held = (True, True, True)  # horizontal, vertical, yaw sticks centred last period

    def activate(self, previous: FlightMode, armed: bool) -> None:
        self.speed_mps = math.nan
        self.state.hold_here()
        self._held = [True, True, True]  # centred sticks leave the held setpoint alone

    def reposition(self, target_ned_m: np.ndarray, yaw_rad: float, speed_mps: float,
                   holding: bool) -> None:
        """Go to ``target_ned_m`` (NaN: keep that coordinate; checked by the commander)
        and hold there, entering HOLD unless ``holding`` already."""
        s = self.state
        held = s.setpoint.position_ned_m
        # What the tool leaves out stays as it is: the held position in HOLD, else the
        # point where the vehicle can stop.
        here = held if holding and np.all(np.isfinite(held)) else s.stopping_point()
        target = np.where(np.isfinite(target_ned_m), target_ned_m, here)
        if np.any(np.abs(target) > 1000.0):
            raise RefusedError("go-to position is more than 1 km from home")
        if not holding:
            self.env.switch_to(FlightMode.HOLD)
        yaw = yaw_rad if math.isfinite(yaw_rad) else s.setpoint.yaw_rad
        s.setpoint = Setpoint.hold(target, yaw)
        self.speed_mps = speed_mps
        self.env.say(f"going to {target[0]:.1f} N {target[1]:.1f} E {-target[2]:.1f} m up")

    def update(self) -> TaskOutput:
        s = self.state
        if s.loiter_sticks:
            s.start_translation()
            self._held = position_control(s.setpoint, s.sticks, s.shaper.yaw_rad,
                                          s.shaper.stopping_point(s.limits), self._held,
                                          s.parameters)
        return s.translate(self.speed_mps)
