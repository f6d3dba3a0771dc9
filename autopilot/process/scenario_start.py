"""Scenario runs: how the vehicle starts flying with no ground tool to arm it.

``--arm-in-reference``: armed in REFERENCE mode at the first control step, wherever the
vehicle is; ``--start-mission``: armed in AUTO.MISSION as soon as the vehicle allows it
(on the estimator, once it has converged). Both on sim time, so a lockstep run stays
reproducible.
"""

from __future__ import annotations

from collections.abc import Callable

from autopilot.commander.commander import Commander
from autopilot.refusal import RefusedError
from contracts.modes import FlightMode


class ScenarioStart:
    """Arms the vehicle before a control step as the scenario asked."""

    def __init__(self, vehicle: Commander, arm_in_reference: bool, start_mission: bool,
                 log: Callable[[str], None]) -> None:
        self.vehicle = vehicle
        self.arm_in_reference = arm_in_reference
        self.start_mission = start_mission  # until armed in AUTO.MISSION
        self.log = log

    def before_step(self, sim_t_s: float, first_step: bool) -> None:
        """Called before each control step, after its sample."""
        vehicle = self.vehicle
        if self.arm_in_reference and not vehicle.armed and first_step:
            vehicle.arm_in_reference()
            self.log(f"flying the {vehicle.reference.kind} reference from t={sim_t_s:.3f} s")
        if self.start_mission:
            self._start_mission(sim_t_s)

    def _start_mission(self, sim_t_s: float) -> None:
        try:
            self.vehicle.set_mode(FlightMode.MISSION, sim_t_s)
            self.vehicle.arm(sim_t_s)
        except RefusedError:
            return
        self.start_mission = False
        self.log(f"flying the mission from t={sim_t_s:.3f} s")
