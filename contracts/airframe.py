"""Airframe description shared by the simulator (truth) and the autopilot (nominal model).

Like PX4's airframe files, one definition is loaded by both sides: the plant integrates
it, the controller's mixer and nominal model read it. Fields carry their units.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from contracts.airframe_file import (
    AirframeError,
    AirframeSpec,
    checked_argument,
    read_airframe,
)
from contracts.frames import GRAVITY_MPS2


class Airframe(NamedTuple):
    """Quadrotor "+" airframe (docs/mathematics.md). Numba-friendly: floats only."""

    mass_kg: float
    ixx_kgm2: float
    iyy_kgm2: float
    izz_kgm2: float
    arm_m: float
    thrust_coeff_ns2: float  # b: rotor thrust = b W^2
    drag_coeff_nms2: float  # d: rotor drag torque = d W^2
    rotor_inertia_kgm2: float  # Jr
    rotor_max_rad_s: float  # W_max [rad/s]
    motor_tau_s: float  # first-order rotor lag, 0 = ideal (the paper)
    linear_drag_nspm: float  # airframe drag against air-relative velocity [N/(m/s)]
    gravity_mps2: float = GRAVITY_MPS2


def airframe_from_spec(spec: AirframeSpec) -> Airframe:
    """The scalar model the controller and mixer fly: the paper's "+" layout (rotors
    front cw, right ccw, rear cw, left ccw at one arm length, alike, diagonal inertia,
    speed command map). Other layouts are refused with the reason."""
    rotors = spec.rotors
    first = rotors[0]
    arm = first.position_m[0]
    layout = ((arm, 0.0, 0.0), (0.0, arm, 0.0), (-arm, 0.0, 0.0), (0.0, -arm, 0.0))
    problems = []
    if len(rotors) != 4 or tuple(r.position_m for r in rotors) != layout:
        problems.append("rotors at front, right, rear, left, one arm length apart")
    elif tuple(r.spin for r in rotors) != (1.0, -1.0, 1.0, -1.0):
        problems.append("spins cw, ccw, cw, ccw")
    elif any((r.thrust_coeff_ns2, r.moment_coeff_nms2, r.max_rad_s, r.time_constant_s,
              r.inertia_kgm2) != (first.thrust_coeff_ns2, first.moment_coeff_nms2,
                                  first.max_rad_s, first.time_constant_s, first.inertia_kgm2)
             for r in rotors):
        problems.append("four alike rotors")
    inertia = spec.inertia_kgm2
    if np.any(inertia != np.diag(np.diag(inertia))):
        problems.append("a diagonal inertia matrix")
    if spec.command_map != "speed":
        problems.append('command_map = "speed"')
    if problems:
        raise AirframeError(f"{spec.source}: the autopilot's controller and mixer fly the "
                            f"\"+\" layout only so far (the simulator flies any); this "
                            f"airframe needs {'; '.join(problems)}")
    return Airframe(
        mass_kg=spec.mass_kg, ixx_kgm2=float(inertia[0, 0]), iyy_kgm2=float(inertia[1, 1]),
        izz_kgm2=float(inertia[2, 2]), arm_m=arm, thrust_coeff_ns2=first.thrust_coeff_ns2,
        drag_coeff_nms2=first.moment_coeff_nms2, rotor_inertia_kgm2=first.inertia_kgm2,
        rotor_max_rad_s=first.max_rad_s, motor_tau_s=first.time_constant_s,
        linear_drag_nspm=spec.linear_drag_nspm)


def airframe_by_name(name: str) -> Airframe:
    """A shipped airframe by name, or an airframe file by path (contracts/airframe_file.py);
    AirframeError (a ValueError) names what is wrong."""
    return airframe_from_spec(read_airframe(name))


airframe_argument = checked_argument(airframe_by_name)  # what the autopilot flies


# The shipped airframes (contracts/airframes/*.toml): the paper's Table 1 with the rotor
# limit W_max = 500 rad/s, and a 450-class vehicle off the paper's design point.
PAPER = airframe_by_name("paper")
REALISTIC = airframe_by_name("realistic")


class AttitudeCoefficients(NamedTuple):
    """The paper's a1..a5, b1..b3 (docs/mathematics.md)."""

    a1: float
    a2: float
    a3: float
    a4: float
    a5: float
    b1: float
    b2: float
    b3: float


def attitude_coefficients(af: Airframe) -> AttitudeCoefficients:
    b1, b2, b3 = input_gains(af)
    return AttitudeCoefficients(
        a1=(af.iyy_kgm2 - af.izz_kgm2) / af.ixx_kgm2,
        a2=af.rotor_inertia_kgm2 / af.ixx_kgm2,
        a3=(af.izz_kgm2 - af.ixx_kgm2) / af.iyy_kgm2,
        a4=af.rotor_inertia_kgm2 / af.iyy_kgm2,
        a5=(af.ixx_kgm2 - af.iyy_kgm2) / af.izz_kgm2,
        b1=b1,
        b2=b2,
        b3=b3,
    )


def hover_rotor_speed_rad_s(af: Airframe) -> float:
    """Rotor speed at which four rotors carry the weight: sqrt(m g / 4b)."""
    return math.sqrt(af.mass_kg * af.gravity_mps2 / (4.0 * af.thrust_coeff_ns2))


@njit(cache=True)
def max_thrust_n(af: Airframe) -> float:
    """Total thrust with every rotor at its top speed: 4 b W_max^2."""
    return 4.0 * af.thrust_coeff_ns2 * af.rotor_max_rad_s**2


@njit(cache=True)
def residual_rotor_speed(rotor_rad_s: np.ndarray) -> float:
    """W_r = W1 - W2 + W3 - W4 [rad/s]: the rotors' net spin in the gyroscopic terms."""
    return rotor_rad_s[0] - rotor_rad_s[1] + rotor_rad_s[2] - rotor_rad_s[3]


@njit(cache=True)
def input_gains(af: Airframe) -> tuple[float, float, float]:
    """b1, b2, b3 of phi'' = f_phi + b1 U_phi, theta'' = f_theta + b2 U_theta,
    psi'' = f_psi + b3 U_psi: arm / Ixx, arm / Iyy, 1 / Izz."""
    return af.arm_m / af.ixx_kgm2, af.arm_m / af.iyy_kgm2, 1.0 / af.izz_kgm2


@njit(cache=True)
def paper_attitude_drift(
    phi_dot: float, theta_dot: float, psi_dot: float, w_r: float, af: Airframe
) -> tuple[float, float, float]:
    """The unknown parts f_phi, f_theta, f_psi of the paper's attitude model (docs/mathematics.md).

    phi'' = f_phi + b1 U_phi etc. The gyroscopic terms have opposite signs on roll and
    pitch (tau_gyro = -omega x Jr W_r e_z).
    """
    ixx, iyy, izz = af.ixx_kgm2, af.iyy_kgm2, af.izz_kgm2
    jr = af.rotor_inertia_kgm2
    f_phi = (iyy - izz) / ixx * theta_dot * psi_dot - jr / ixx * theta_dot * w_r
    f_theta = (izz - ixx) / iyy * phi_dot * psi_dot + jr / iyy * phi_dot * w_r
    f_psi = (ixx - iyy) / izz * phi_dot * theta_dot
    return f_phi, f_theta, f_psi
