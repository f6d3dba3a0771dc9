"""AUTO.MISSION: fly the navigator's goals (autopilot/navigator/) through the shaper. A
mission ending in a return hands over to AUTO.RTL; a mission cleared in flight, to HOLD."""

from __future__ import annotations

from autopilot.flight_tasks.task import BaseTask, TaskOutput
from contracts.modes import FlightMode


class MissionTask(BaseTask):
    def activate(self, previous: FlightMode, armed: bool) -> None:
        if armed:
            self.restart()

    def on_arm(self) -> None:
        self.state.hold_here()
        self.restart()

    def restart(self) -> bool:
        """Start or resume the mission at its current item; True if it handed over to a
        return at once."""
        s = self.state
        if self.env.navigator.start(s.stopping_point(), s.heading_rad, s.landed,
                                    s.parameters):
            self.env.switch_to(FlightMode.RTL)
            return True
        return False

    def update(self) -> TaskOutput | None:
        s, nav = self.state, self.env.navigator
        if nav.uploaded_anew:  # fly a new mission from its first item, as PX4 does
            if not nav.mission:  # ... or hold without one
                self.env.say("mission cleared: holding", 4)
                nav.runner = None
                self.env.switch_to(FlightMode.HOLD)
                return None
            if self.restart():
                return None
        elif nav.current_moved and self.restart():  # a tool set the current item
            return None
        goal = nav.step(s.sim_t_s, s.position_ned_m, s.reference_position_ned_m(),
                        s.parameters, s.reference_velocity_ned_mps())
        if goal is None:
            self.env.switch_to(FlightMode.RTL)
            return None
        s.setpoint = goal.setpoint
        return s.translate(goal.speed_mps, goal.vertical)

    @property
    def landing(self) -> bool:
        runner = self.env.navigator.runner
        return runner is not None and runner.landing
