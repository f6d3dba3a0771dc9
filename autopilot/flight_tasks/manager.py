"""The control step (PX4's flight mode manager feeding its multicopter controllers): the
current mode's flight task gives the reference, the controller the motor commands."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from autopilot.control.controller import Controller
from autopilot.flight_tasks.task import FlightTask, Shaped, TaskOutput, TaskState
from contracts.modes import FlightMode
from contracts.perturbation_book import PerturbationBook
from contracts.perturbations import kick_at
from contracts.vectors import REF_SIZE


class FlightControl:
    """The flight tasks, the controller, and what the last step gave them."""

    def __init__(self, state: TaskState, tasks: dict[FlightMode, FlightTask],
                 controller: Controller, perturbations: PerturbationBook) -> None:
        self.state = state
        self.tasks = tasks
        self.controller = controller
        self.perturbations = perturbations  # reference kicks, in sim time
        self.last_ref = np.zeros(REF_SIZE)
        self.last_kick = np.zeros(2)
        self.last_commands = np.zeros(4)

    def idle(self) -> np.ndarray:
        """Disarmed or without state: no shaping, motors off (the setpoints' sim time goes
        on with the samples all the same)."""
        self.state.begin_step()
        self.state.shaped = Shaped.NONE
        self.last_commands = np.zeros(4)
        return self.last_commands

    def step(self, mode: Callable[[], FlightMode], tilt_limited: bool) -> np.ndarray:
        """Motor commands for this period in the mode ``mode()`` says (a task may hand
        over to another mode within the step); ``tilt_limited``: PX4's MPC_TILTMAX_AIR
        limits the total tilt (the paper's reference keeps its per-axis clip)."""
        self.state.begin_step()
        out = self._reference(mode)
        entries = self.perturbations.entries
        kick = np.array(kick_at(entries, self.state.sim_t_s)) if entries else np.zeros(2)
        self.last_ref, self.last_kick = out.reference, kick
        self.last_commands = self.controller.step(
            self.state.measurement, out.reference, out.position_mode, kick, out.thrust_n,
            tilt_limited)
        return self.last_commands

    def _reference(self, mode: Callable[[], FlightMode]) -> TaskOutput:
        out = self.tasks[mode()].update()
        if out is None:  # handed over: the next mode's task flies this period
            out = self.tasks[mode()].update()
        self.tasks[FlightMode.TAKEOFF].check_reached(mode() is FlightMode.TAKEOFF)
        return out
