"""TAKEOFF (PX4's AUTO.TAKEOFF): climb straight up at MPC_TKO_SPEED to the take-off
altitude; the commander holds there once it is reached."""

from __future__ import annotations

from autopilot.flight_tasks.task import BaseTask, Shaped, TaskOutput
from contracts.modes import FlightMode
from contracts.vectors import MEAS_Z

TAKEOFF_REACHED_M = 0.1


class TakeoffTask(BaseTask):
    def climb_to(self, altitude_m: float) -> None:
        """Hold here, at ``altitude_m`` above home (the climb's limits apply while the
        state's take-off altitude, in the local frame, is set)."""
        s = self.state
        local_m = self.env.navigator.places.local_altitude_m(altitude_m)
        s.hold_here()
        s.setpoint.position_ned_m[2] = -local_m
        s.takeoff_altitude_m = local_m

    def update(self) -> TaskOutput:
        return self.state.translate()

    def check_reached(self, in_takeoff_mode: bool) -> None:
        """After a shaped step of any mode: a climb within TAKEOFF_REACHED_M of its
        altitude is complete; in TAKEOFF mode the vehicle then holds that altitude."""
        s = self.state
        if s.takeoff_altitude_m is None or s.shaped is not Shaped.TRANSLATION or \
                abs(s.measurement[MEAS_Z] + s.takeoff_altitude_m) >= TAKEOFF_REACHED_M:
            return
        self.env.say("take-off complete")
        s.takeoff_altitude_m = None
        if in_takeoff_mode:
            target = s.setpoint  # hold the take-off altitude, not where it is
            self.env.switch_to(FlightMode.HOLD)
            s.setpoint = target
