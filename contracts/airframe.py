"""Airframe description shared by the simulator (truth) and the autopilot (nominal model).

Like PX4's airframe files, one definition is loaded by both sides: the plant integrates
it, the controller's mixer and nominal model read it. Fields carry their units.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

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


# Paper Table 1, with the rotor limit of docs/mathematics.md (thrust-to-weight 4.6).
PAPER = Airframe(
    mass_kg=1.2,
    ixx_kgm2=0.18,
    iyy_kgm2=0.18,
    izz_kgm2=0.09,
    arm_m=0.23,
    thrust_coeff_ns2=54.2e-6,
    drag_coeff_nms2=1.1e-6,
    rotor_inertia_kgm2=1.32e-3,
    rotor_max_rad_s=500.0,
    motor_tau_s=0.0,
    linear_drag_nspm=0.0,
)

# A 450-class quadrotor with measured-looking numbers: lighter inertia, a real motor lag
# and airframe drag, so the paper-tuned controller is tested off its design point.
REALISTIC = Airframe(
    mass_kg=1.5,
    ixx_kgm2=0.0215,
    iyy_kgm2=0.0215,
    izz_kgm2=0.0380,
    arm_m=0.225,
    thrust_coeff_ns2=1.22e-5,
    drag_coeff_nms2=1.9e-7,
    rotor_inertia_kgm2=6.0e-5,
    rotor_max_rad_s=1100.0,
    motor_tau_s=0.02,
    linear_drag_nspm=0.25,
)

AIRFRAMES: dict[str, Airframe] = {"paper": PAPER, "realistic": REALISTIC}


def airframe_by_name(name: str) -> Airframe:
    """Look an airframe up by name, with an error that lists the known ones."""
    try:
        return AIRFRAMES[name]
    except KeyError:
        known = ", ".join(sorted(AIRFRAMES))
        raise ValueError(f"unknown airframe {name!r}; known airframes: {known}") from None


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
