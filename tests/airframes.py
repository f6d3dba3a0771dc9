"""The paper's "+" vehicle as the scalars of its Table 1, to write its equations out by
hand in tests, and "+" airframes built from such scalars."""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from contracts.airframe import Airframe, airframe_from_spec
from contracts.airframe_file import SPINS, AirframeSpec, RotorSpec, read_airframe


class PlusNumbers(NamedTuple):
    mass_kg: float
    ixx_kgm2: float
    iyy_kgm2: float
    izz_kgm2: float
    arm_m: float
    thrust_coeff_ns2: float  # b
    drag_coeff_nms2: float  # d
    rotor_inertia_kgm2: float  # Jr
    rotor_max_rad_s: float
    motor_tau_s: float
    linear_drag_nspm: float


def plus_numbers(name: str) -> PlusNumbers:
    """The scalars of a shipped "+" airframe (rotors alike, diagonal inertia)."""
    spec = read_airframe(name)
    r = spec.rotors[0]
    ixx, iyy, izz = np.diag(spec.inertia_kgm2)
    return PlusNumbers(spec.mass_kg, float(ixx), float(iyy), float(izz), r.position_m[0],
                       r.thrust_coeff_ns2, r.moment_coeff_nms2, r.inertia_kgm2, r.max_rad_s,
                       r.time_constant_s, spec.linear_drag_nspm)


def plus_airframe(n: PlusNumbers) -> Airframe:
    """Rotors front (cw), right (ccw), rear (cw), left (ccw) at the arm length: the
    paper's layout and motor order."""
    arm = n.arm_m
    rotors = tuple(RotorSpec(position, SPINS[spin], n.thrust_coeff_ns2, n.drag_coeff_nms2,
                             n.rotor_max_rad_s, n.motor_tau_s, n.rotor_inertia_kgm2)
                   for position, spin in (((arm, 0.0, 0.0), "cw"), ((0.0, arm, 0.0), "ccw"),
                                          ((-arm, 0.0, 0.0), "cw"), ((0.0, -arm, 0.0), "ccw")))
    return airframe_from_spec(AirframeSpec(
        "+", "", n.mass_kg, np.diag([n.ixx_kgm2, n.iyy_kgm2, n.izz_kgm2]),
        n.linear_drag_nspm, "speed", rotors, "test airframe"))


PAPER_NUMBERS = plus_numbers("paper")
REALISTIC_NUMBERS = plus_numbers("realistic")
