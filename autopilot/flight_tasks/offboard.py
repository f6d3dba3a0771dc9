"""Setpoints streamed by a tool: PX4's OFFBOARD and ArduPilot's GUIDED. A position /
velocity setpoint is shaped; an attitude target flies through the attitude shaper."""

from __future__ import annotations

import math

import numpy as np

from autopilot.flight_tasks.task import BaseTask, TaskEnv, TaskOutput
from contracts.modes import FlightMode
from contracts.vectors import MEASUREMENT

ROI_NEAR_M = 1.0  # closer than this to the region of interest, the heading stays


class OffboardTask(BaseTask):
    """``streams``: OFFBOARD, which flies the newest streamed setpoint from entry (and
    needs the stream); GUIDED holds on entry (unless coming from OFFBOARD) until a
    setpoint comes."""

    def __init__(self, env: TaskEnv, streams: bool) -> None:
        super().__init__(env)
        self.streams = streams
        self.roi_ned_m: np.ndarray | None = None  # Copter's DO_SET_ROI in GUIDED

    def activate(self, previous: FlightMode, armed: bool) -> None:
        self.roi_ned_m = None  # a region of interest lasts while the mode does
        if self.streams:
            self.state.apply_streamed()
        elif previous is not FlightMode.OFFBOARD:
            self.state.hold_here()

    def on_arm(self) -> None:
        if self.streams:
            self.state.apply_streamed()
        else:
            self.state.hold_here()

    def update(self) -> TaskOutput:
        s = self.state
        if s.attitude_target is not None:
            return s.attitude()
        if self.roi_ned_m is not None:  # the nose on the region of interest
            here = s.measurement[MEASUREMENT.position_ned_m]
            north, east = self.roi_ned_m[0] - here[0], self.roi_ned_m[1] - here[1]
            if math.hypot(north, east) >= ROI_NEAR_M:
                s.setpoint.yaw_rad = math.atan2(east, north)
                s.setpoint.yaw_rate_rad_s = math.nan
        return s.translate()
