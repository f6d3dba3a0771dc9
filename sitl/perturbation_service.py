"""The simulator's perturbations: its schedule and the requests taken since, applied at
each sample's sim time to the plant (``Perturbations``) and to what the autopilot is sent
(``SensorEffects``); each entry's start and end published and logged.

A ``sim_stall`` freezes the whole process when it starts, as a suspended or overloaded
simulator would stop: no physics, no samples, no requests served.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

from contracts import SITL
from contracts.perturbation_book import PerturbationBook
from contracts.perturbations import (
    NO_SENSOR_EFFECTS,
    Perturbation,
    Perturbations,
    SensorEffects,
    plant_perturbations_at,
    sensor_effects_at,
)
from contracts.telemetry_node import Request
from sitl.plant import Plant

EventSink = Callable[[int, str, Perturbation], None]  # (sim time [us], event, entry)


class PerturbationService:
    """The book of the simulator's perturbations and what is in force at the last sample:
    ``active`` on the plant, ``sensor_effects`` on the link."""

    def __init__(self, schedule: tuple[Perturbation, ...], plant: Plant,
                 publish_event: EventSink, log: Callable[[str], None]) -> None:
        self.book = PerturbationBook(SITL, schedule)
        self.plant = plant
        self.publish_event = publish_event
        self.log = log
        self.active = Perturbations()
        self.sensor_effects: SensorEffects = NO_SENSOR_EFFECTS

    def update(self, time_us: int) -> None:
        """Apply what is in force at the sample at ``time_us``; say what started or ended."""
        entries = self.book.entries
        if not entries:
            return
        t_s = time_us / 1e6
        wanted = plant_perturbations_at(entries, t_s)
        if wanted != self.active:
            self.plant.set_perturbations(wanted)
            self.active = wanted
        self.sensor_effects = sensor_effects_at(entries, t_s)
        for event, e in self.book.changes(t_s):
            self.publish_event(time_us, event, e)
            self.log(f"t={t_s:.3f} s perturbation {e.id} ({e.kind}) {event}")
            if event == "start" and e.kind == "sim_stall":
                self._freeze(e.params["freeze_s"])

    def answer(self, request: Request, time_us: int) -> None:
        """A ``perturb`` request (add, clear, list) at sim time ``time_us``; a bad one
        raises ValueError and changes nothing."""
        answer: dict[str, Any] = self.book.handle(request.data, time_us / 1e6)
        self.log(f"perturbation request answered: {answer}")
        request.reply(True, sim_time_us=time_us, **answer)

    def _freeze(self, freeze_s: float) -> None:
        """A stalled simulator: the whole process stops (no physics, no samples, no
        requests served), as a suspended or overloaded one would."""
        self.log(f"frozen for {freeze_s:g} s of wall time (sim_stall)")
        time.sleep(freeze_s)
