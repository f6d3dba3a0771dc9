"""The manual modes, flown from MANUAL_CONTROL's sticks (autopilot/flight_tasks/sticks.py
reads them as PX4 does): POSCTL through the translation shaper, ALTCTL and STABILIZED
through the attitude shaper, as an attitude setpoint from a tool would be."""

from __future__ import annotations

from autopilot.flight_tasks.sticks import attitude_control, climb_stick, position_control
from autopilot.flight_tasks.task import BaseTask, TaskEnv, TaskOutput
from contracts.modes import FlightMode


class ManualTask(BaseTask):
    def activate(self, previous: FlightMode, armed: bool) -> None:
        self.state.hold_here()

    @property
    def landing(self) -> bool:
        """The throttle stick down: descending, which lands."""
        s = self.state
        return climb_stick(s.sticks.throttle, s.parameters) < 0.0


class PositionControlTask(ManualTask):
    """POSCTL: sticks command velocities; a centred stick holds that axis."""

    def activate(self, previous: FlightMode, armed: bool) -> None:
        super().activate(previous, armed)
        self._held = [False, False, False]  # horizontal, vertical, yaw held last period

    def update(self) -> TaskOutput:
        s = self.state
        s.start_translation()
        shaper = s.shaper
        self._held = position_control(s.setpoint, s.sticks, shaper.yaw_rad,
                                      shaper.stopping_point(s.limits), self._held,
                                      s.parameters)
        return TaskOutput(s.shape_translation(s.limits))


class AttitudeControlTask(ManualTask):
    """ALTCTL (the throttle a climb rate) and STABILIZED (``thrust_stick``: the throttle
    is the collective thrust, hover at mid stick)."""

    def __init__(self, env: TaskEnv, thrust_stick: bool) -> None:
        super().__init__(env)
        self.thrust_stick = thrust_stick

    def update(self) -> TaskOutput:
        s = self.state
        hover = s.hover_fraction if self.thrust_stick else None
        s.streamed = attitude_control(s.sticks, s.parameters, hover)
        s.apply_streamed()
        return s.attitude()
