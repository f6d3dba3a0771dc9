"""Setpoints streamed by a tool: PX4's OFFBOARD and ArduPilot's GUIDED. A position /
velocity setpoint is shaped; an attitude target flies through the attitude shaper."""

from __future__ import annotations

from autopilot.flight_tasks.task import BaseTask, TaskEnv, TaskOutput
from contracts.modes import FlightMode


class OffboardTask(BaseTask):
    """``streams``: OFFBOARD, which flies the newest streamed setpoint from entry (and
    needs the stream); GUIDED holds on entry (unless coming from OFFBOARD) until a
    setpoint comes."""

    def __init__(self, env: TaskEnv, streams: bool) -> None:
        super().__init__(env)
        self.streams = streams

    def activate(self, previous: FlightMode, armed: bool) -> None:
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
        if self.state.attitude_target is not None:
            return self.state.attitude()
        return self.state.translate()
