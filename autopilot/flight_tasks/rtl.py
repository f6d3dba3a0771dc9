"""AUTO.RTL: fly the navigator's return (autopilot/navigator/rtl.py) through the shaper."""

from __future__ import annotations

from autopilot.flight_tasks.task import BaseTask, TaskOutput
from autopilot.navigator.rtl import ReturnToLaunch
from contracts.modes import FlightMode


class ReturnTask(BaseTask):
    returning: ReturnToLaunch | None = None

    def activate(self, previous: FlightMode, armed: bool) -> None:
        s = self.state
        self.returning = ReturnToLaunch(s.parameters, self.env.navigator.places.home_ned_m)
        self.returning.start(s.stopping_point(), s.heading_rad)

    def update(self) -> TaskOutput:
        s = self.state
        self.returning.parameters = s.parameters  # changed in flight: they apply at once
        goal = self.returning.step(s.position_ned_m, s.reference_position_ned_m())
        s.setpoint = goal.setpoint
        return s.translate(goal.speed_mps, goal.vertical)

    @property
    def landing(self) -> bool:
        return self.returning is not None and self.returning.landing
