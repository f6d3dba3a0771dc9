"""REFERENCE mode's flight task: the paper's reference (autopilot/trajectories.py) flown
in sim time from when it began."""

from __future__ import annotations

import math

from autopilot.flight_tasks.task import BaseTask, Shaped, TaskOutput
from contracts.modes import FlightMode


class ReferenceTask(BaseTask):
    """The paper's reference (REFERENCE mode), in sim time from when it began; not shaped
    (the paper's controller is tuned on it as it is)."""

    start_s = 0.0

    def activate(self, previous: FlightMode, armed: bool) -> None:
        self.begin()

    def begin(self) -> None:
        self.start_s = self.state.sim_t_s

    def update(self) -> TaskOutput:
        s, reference = self.state, self.env.reference
        s.shaped = Shaped.NONE
        return TaskOutput(reference.at(s.sim_t_s - self.start_s), reference.position_mode,
                          math.nan)
