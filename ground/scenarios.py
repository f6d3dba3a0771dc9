"""The paper's six scenarios (SPEC section 6) as data.

A scenario is a reference, a schedule of perturbation windows in sim time, a duration
and the axes it is judged on (after a stated transient).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from autopilot.reference import Reference
from contracts.schedule import Perturbations, Window, kick_at, plant_perturbations_at

ATTITUDE_AXES = ("phi", "theta", "psi", "z")
POSITION_AXES = ("x", "y", "z", "psi")


@dataclass(frozen=True)
class Scenario:
    name: str
    description: str
    reference: Reference
    axes: tuple[str, ...]
    transient_s: float
    duration_s: float = 20.0
    windows: tuple[Window, ...] = field(default_factory=tuple)

    def plant_perturbations_at(self, t_s: float) -> Perturbations:
        return plant_perturbations_at(self.windows, t_s)

    def kick_at(self, t_s: float) -> tuple[float, float]:
        return kick_at(self.windows, t_s)


def _inertia_test(percent: int) -> Scenario:
    scale = 1.0 + percent / 100.0
    return Scenario(
        name=f"attitude-jr-{percent}",
        description=f"attitude-sine with Jr and I raised by {percent} % for t in [12, 14] s",
        reference=Reference("attitude-sine"),
        axes=ATTITUDE_AXES,
        transient_s=2.0,
        windows=(Window(12.0, 14.0, Perturbations(inertia_scale=scale,
                                                   rotor_inertia_scale=scale)),),
    )


SCENARIOS: dict[str, Scenario] = {
    s.name: s
    for s in (
        Scenario("attitude-sine", "theta_d = sin t, phi_d = sin(t + pi), psi_d = 0.2, 1 m",
                 Reference("attitude-sine"), ATTITUDE_AXES, transient_s=2.0),
        Scenario("attitude-hold", "attitude-sine with all angles held at 0 (psi 0.2) in [10, 12] s",
                 Reference("attitude-hold"), ATTITUDE_AXES, transient_s=2.0),
        Scenario("position-sine", "x_d = sin t, y_d = sin(t + pi), 1 m, psi_d = 0.2",
                 Reference("position-sine"), POSITION_AXES, transient_s=3.0),
        _inertia_test(10),
        _inertia_test(15),
        _inertia_test(20),
        Scenario("position-kick",
                 "position-sine, +0.25 rad on phi_d in [8, 8.5] s and on theta_d in [9, 9.5] s",
                 Reference("position-sine"), POSITION_AXES, transient_s=3.0,
                 windows=(Window(8.0, 8.5, kick_rad=(0.25, 0.0)),
                          Window(9.0, 9.5, kick_rad=(0.0, 0.25)))),
    )
}


def scenario_by_name(name: str) -> Scenario:
    try:
        return SCENARIOS[name]
    except KeyError:
        known = ", ".join(SCENARIOS)
        raise ValueError(f"unknown scenario {name!r}; known scenarios: {known}") from None
