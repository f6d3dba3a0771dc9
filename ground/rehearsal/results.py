"""What a rehearsal found: each flight's result (with the reference sleeper's figures
beside a real-time one) and the rehearsal's checks, verdict and advice. Pure: the
outputs (``outputs.py``) are written from these."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from ground.check.checker import ScenarioResult
from ground.rehearsal.readiness import ADVICE, Flight, Profile
from ground.scenario.expectations import Outcome

# What to change when one expectation fails, whatever the flight (else the flight's advice).
EXPECTATION_ADVICE = {
    "control.tilt_rate_rms_rad_s": "roll and pitch swing in a limit cycle: raise "
                                   "CMDF_ACC_MAX (the desired-angle filter's acceleration "
                                   "limit; 20 rad/s^2 on the quad X 500), or soften the "
                                   "position loop (POS_EPS)",
}


@dataclass
class FlightResult:
    flight: Flight
    result: ScenarioResult
    # Real time: the reference sleeper's figures over the autopilot's loop (None: not
    # run; {"error": why} when it could not run).
    reference: dict[str, Any] | None = None

    @property
    def name(self) -> str:
        return self.result.scenario.name

    def _timing(self, key: str) -> int | None:
        value = ((self.result.metrics or {}).get("timing") or {}).get(key)
        return None if value is None else int(value)

    @property
    def deadline_misses(self) -> int | None:
        """The autopilot's deadline misses (None: not measured, a lockstep flight)."""
        return self._timing("deadline_misses")

    @property
    def steps_held(self) -> int | None:
        """Control steps the autopilot held in simulator stalls: a stall of the machine
        that holds the simulator too is counted so, not as deadline misses."""
        return self._timing("sim_stall_steps")

    def machine_note(self) -> str:
        """What the reference says of this flight's timing, in one sentence ('' without
        a reference)."""
        ref = self.reference
        if not ref:
            return ""
        if "error" in ref:
            return f"no reference sleeper: {ref['error']}"
        lost = ref["lost_periods"]
        same = f"in the same {ref['window_s']:.0f} s the reference sleeper ({ref['source']})"
        if lost:
            return (f"{same} lost {lost} period(s), its worst wake-up {ref['worst_ms']:.1f} ms "
                    f"late: the machine misses deadlines with none of our code")
        return (f"{same} lost none (worst wake-up {ref['worst_ms']:.2f} ms late): the "
                f"machine kept time")


@dataclass
class Rehearsal:
    airframe: str
    airframe_name: str
    profile: Profile
    rate_hz: float
    sensors: str | None
    model: str  # where the model came from
    parameters: dict[str, float]
    given: dict[str, float] = field(default_factory=dict)  # set on the command line
    static: list[Outcome] = field(default_factory=list)
    flights: list[FlightResult] = field(default_factory=list)
    not_flown: str | None = None  # why the flights were not flown
    wall_time_s: float = 0.0

    @property
    def passed(self) -> bool:
        return (self.not_flown is None and all(o.passed for o in self.static)
                and all(f.result.passed for f in self.flights))

    @property
    def verdict(self) -> str:
        return "GO" if self.passed else "NO-GO"

    def failed_checks(self) -> list[tuple[str, Outcome, str]]:
        """(group, outcome, what to change) of every failed check."""
        out = [("static", o, _static_advice(o)) for o in self.static if not o.passed]
        for f in self.flights:
            if f.result.error is not None:
                out.append((f.name, Outcome("flight", False, None, None, f.result.error),
                            f.flight.advice))
            out += [(f.name, o, _with_machine_note(
                f, o, EXPECTATION_ADVICE.get(o.name.split(" ")[0], f.flight.advice)))
                for o in f.result.failures]
        return out


def _with_machine_note(f: FlightResult, outcome: Outcome, advice: str) -> str:
    """A failed timing check's advice, after what the reference says of the machine."""
    note = f.machine_note() if outcome.name.startswith("timing.") else ""
    if not note:
        return advice
    return f"{note[0].upper()}{note[1:]}." + (f" {advice[0].upper()}{advice[1:]}" if advice
                                               else "")


def _static_advice(outcome: Outcome) -> str:
    if outcome.measured is None and outcome.limit is not None:
        return ""  # not measurable: the airframe check says why
    key = "parameters" if outcome.name.startswith("parameter ") else outcome.name
    return ADVICE.get(key, "")
