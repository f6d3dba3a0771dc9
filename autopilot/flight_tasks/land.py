"""LAND (PX4's AUTO.LAND): descend where the vehicle is at MPC_LAND_SPEED; the commander
disarms COM_DISARM_LAND after touchdown."""

from __future__ import annotations

from autopilot.flight_tasks.goal import LAND_DOWN_M, Vertical
from autopilot.flight_tasks.task import BaseTask, TaskOutput
from contracts.modes import FlightMode


class LandTask(BaseTask):
    def activate(self, previous: FlightMode, armed: bool) -> None:
        self.state.hold_here()
        self.state.setpoint.position_ned_m[2] = LAND_DOWN_M

    def update(self) -> TaskOutput:
        return self.state.translate(vertical=Vertical.LAND)

    @property
    def landing(self) -> bool:
        return True
