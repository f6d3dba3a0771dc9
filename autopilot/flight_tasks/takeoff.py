"""TAKEOFF (PX4's AUTO.TAKEOFF): climb straight up at MPC_TKO_SPEED to the take-off
altitude; the commander holds there once it is reached."""

from __future__ import annotations

from autopilot.flight_tasks.task import BaseTask, TaskOutput


class TakeoffTask(BaseTask):
    def climb_to(self, altitude_m: float) -> None:
        """Hold here, at ``altitude_m`` above home (the climb's limits apply while the
        state's take-off altitude is set)."""
        s = self.state
        s.hold_here()
        s.setpoint.position_ned_m[2] = -altitude_m
        s.takeoff_altitude_m = altitude_m

    def update(self) -> TaskOutput:
        return self.state.translate()
