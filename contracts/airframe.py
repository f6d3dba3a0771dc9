"""The airframe as numbers: what the simulator integrates (truth) and what the autopilot's
mixer and nominal model read, built once from an airframe file (contracts/airframe_file.py).

Like PX4's airframe files, one definition is loaded by both sides. Any quadrotor geometry
flies: the rotors enter only through the effectiveness matrix and its inverse.

The controller's attitude inputs are the paper's (docs/mathematics.md):
phi'' = f_phi + b1 U_phi, theta'' = f_theta + b2 U_theta, psi'' = f_psi + b3 U_psi, with
U_phi and U_theta the roll and pitch torques expressed as forces at the reference arms
(the largest |y_i| and |x_i| of the rotors; the paper's arm l for its "+"), U_psi the yaw
torque, b = (l_roll / Ixx, l_pitch / Iyy, 1 / Izz). With products of inertia the torque
that gives angular acceleration b * U is I (b * U), so the three channels stay decoupled.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from contracts.airframe_file import (
    AirframeError,
    AirframeSpec,
    read_airframe,
)
from contracts.frames import GRAVITY_MPS2

__all__ = ["Airframe", "AirframeError", "airframe_from_spec", "airframe_by_name"]


class Airframe(NamedTuple):
    """A quadrotor as arrays (numba-friendly), rotors in motor order."""

    mass_kg: float
    inertia_kgm2: np.ndarray  # 3x3, body FRD
    inertia_inv: np.ndarray
    linear_drag_nspm: float  # airframe drag against air-relative velocity [N/(m/s)]
    gravity_mps2: float
    effectiveness: np.ndarray  # 4x4: thrust [N], roll, pitch, yaw torque [N m] per W_i^2
    spin: np.ndarray  # +1 clockwise seen from above, -1 counter-clockwise
    rotor_inertia_kgm2: np.ndarray  # Jr per rotor
    max_rad_s: np.ndarray  # W_max per rotor
    time_constant_s: np.ndarray  # first-order rotor lag, 0 = ideal (the paper)
    thrust_command_map: bool  # c -> thrust c T_max (else rotor speed c W_max)
    input_gains: np.ndarray  # b1, b2, b3 (nominal)
    input_map: np.ndarray  # 4x4: U_z, U_phi, U_theta, U_psi per W_i^2
    mixing: np.ndarray  # 4x4 inverse of input_map: W_i^2 per unit of each input


def _reference_arms(spec: AirframeSpec) -> tuple[float, float]:
    return (max(abs(r.position_m[1]) for r in spec.rotors),
            max(abs(r.position_m[0]) for r in spec.rotors))


def airframe_from_spec(spec: AirframeSpec, gravity_mps2: float = GRAVITY_MPS2) -> Airframe:
    """The numbers of an airframe file (four rotors, in motor order)."""
    inertia = np.array(spec.inertia_kgm2, dtype=float)
    effectiveness = spec.effectiveness()
    l_roll, l_pitch = _reference_arms(spec)
    diagonal = np.diag(inertia).copy()
    gains = np.array([l_roll / diagonal[0], l_pitch / diagonal[1], 1.0 / diagonal[2]])
    input_map = np.empty((4, 4))
    input_map[0] = effectiveness[0]
    if np.all(inertia == np.diag(diagonal)):
        # Written from the geometry so the paper's "+" gives U_phi = T4 - T2 exactly.
        for i, r in enumerate(spec.rotors):
            input_map[1, i] = -(r.position_m[1] / l_roll) * r.thrust_coeff_ns2
            input_map[2, i] = (r.position_m[0] / l_pitch) * r.thrust_coeff_ns2
        input_map[3] = effectiveness[3]
    else:
        # U = (1 / b) I^-1 tau: the input whose channel alone gets the acceleration.
        input_map[1:] = (np.linalg.inv(inertia) @ effectiveness[1:]) / gains[:, None]
    mixing = np.linalg.inv(input_map)
    return Airframe(
        mass_kg=spec.mass_kg, inertia_kgm2=inertia, inertia_inv=np.linalg.inv(inertia),
        linear_drag_nspm=spec.linear_drag_nspm, gravity_mps2=gravity_mps2,
        effectiveness=effectiveness,
        spin=np.array([r.spin for r in spec.rotors]),
        rotor_inertia_kgm2=np.array([r.inertia_kgm2 for r in spec.rotors]),
        max_rad_s=np.array([r.max_rad_s for r in spec.rotors]),
        time_constant_s=np.array([r.time_constant_s for r in spec.rotors]),
        thrust_command_map=spec.command_map == "thrust",
        input_gains=gains, input_map=input_map, mixing=mixing)


def airframe_by_name(name: str) -> Airframe:
    """A shipped airframe by name, or an airframe file by path (contracts/airframe_file.py);
    AirframeError (a ValueError) names what is wrong."""
    return airframe_from_spec(read_airframe(name))


# Shipped airframes (contracts/airframes/*.toml): the paper's Table 1 with the rotor limit
# W_max = 500 rad/s, and a 450-class "+" vehicle off the paper's design point.
PAPER_SPEC = read_airframe("paper")
PAPER = airframe_from_spec(PAPER_SPEC)
# The vehicle `ivfm sitl` and `ivfm autopilot` give ground tools unless told otherwise, as
# PX4 SITL's is its x500; the paper's scenarios name the paper's airframe.
DEFAULT_AIRFRAME = "quad-x-500"
REALISTIC = airframe_by_name("realistic")


class AttitudeCoefficients(NamedTuple):
    """The paper's a1..a5, b1..b3 (docs/mathematics.md), from the diagonal of the inertia
    matrix and rotor 1's inertia: its model of a "+" vehicle with alike rotors."""

    a1: float
    a2: float
    a3: float
    a4: float
    a5: float
    b1: float
    b2: float
    b3: float


def attitude_coefficients(af: Airframe) -> AttitudeCoefficients:
    ixx, iyy, izz = np.diag(af.inertia_kgm2)
    jr = af.rotor_inertia_kgm2[0]
    b1, b2, b3 = af.input_gains
    return AttitudeCoefficients(
        a1=float((iyy - izz) / ixx), a2=float(jr / ixx), a3=float((izz - ixx) / iyy),
        a4=float(jr / iyy), a5=float((ixx - iyy) / izz), b1=float(b1), b2=float(b2),
        b3=float(b3))


def hover_rotor_speeds(af: Airframe) -> np.ndarray:
    """Rotor speeds that carry the weight with no torque [rad/s]."""
    return np.sqrt(af.mixing[:, 0] * af.mass_kg * af.gravity_mps2)


@njit(cache=True)
def max_thrust_n(af: Airframe) -> float:
    """The largest collective thrust with no torque: until the first rotor is at its top."""
    best = math.inf
    for i in range(4):
        best = min(best, af.max_rad_s[i] * af.max_rad_s[i] / af.mixing[i, 0])
    return best


@njit(cache=True)
def rotor_speeds(commands: np.ndarray, af: Airframe) -> np.ndarray:
    """Rotor speeds [rad/s] for motor commands c_i in [0, 1] through the command map:
    c W_max (speed), or the speed giving thrust c T_max: sqrt(c) W_max (thrust)."""
    out = np.empty(4)
    for i in range(4):
        c = min(max(commands[i], 0.0), 1.0)
        out[i] = (math.sqrt(c) if af.thrust_command_map else c) * af.max_rad_s[i]
    return out


@njit(cache=True)
def residual_rotor_speed(rotor_rad_s: np.ndarray, af: Airframe) -> float:
    """W_r = sum s_i W_i [rad/s]: the rotors' net spin in the gyroscopic terms (the
    paper's W1 - W2 + W3 - W4 for its "+")."""
    total = 0.0
    for i in range(4):
        total += af.spin[i] * rotor_rad_s[i]
    return total


@njit(cache=True)
def rotor_momentum(rotor_rad_s: np.ndarray, af: Airframe) -> float:
    """h_r = sum Jr_i s_i W_i [kg m^2/s] along +z_b (the paper's Jr W_r)."""
    total = 0.0
    for i in range(4):
        total += af.rotor_inertia_kgm2[i] * af.spin[i] * rotor_rad_s[i]
    return total


@njit(cache=True)
def controller_inputs(rotor_rad_s: np.ndarray, efficiency: np.ndarray,
                      af: Airframe) -> tuple[float, float, float, float]:
    """(U_z, U_phi, U_theta, U_psi) the rotors give; ``efficiency`` scales each rotor's
    thrust and drag (1 healthy, 0 failed)."""
    out = np.zeros(4)
    for i in range(4):
        w2 = efficiency[i] * rotor_rad_s[i] * rotor_rad_s[i]
        for row in range(4):
            out[row] += af.input_map[row, i] * w2
    return out[0], out[1], out[2], out[3]


@njit(cache=True)
def attitude_drift(phi_dot: float, theta_dot: float, psi_dot: float, h_r: float,
                   af: Airframe) -> tuple[float, float, float]:
    """The unknown parts f_phi, f_theta, f_psi of the attitude model (docs/mathematics.md):
    f = -I^-1 (w x (I w + h_r e_z)) with the Euler rates for w (the paper's small-angle
    model). For a diagonal inertia this is the paper's a1 theta' psi' - a2 theta' W_r etc.:
    the gyroscopic terms have opposite signs on roll and pitch."""
    i = af.inertia_kgm2
    p, q, r = phi_dot, theta_dot, psi_dot
    # -w x (I w), the diagonal part written as the paper's differences of inertia (so
    # Ixx = Iyy gives f_psi = 0 exactly), then the products of inertia.
    mx = (i[1, 1] - i[2, 2]) * q * r
    my = (i[2, 2] - i[0, 0]) * r * p
    mz = (i[0, 0] - i[1, 1]) * p * q
    if i[0, 1] != 0.0 or i[0, 2] != 0.0 or i[1, 2] != 0.0:
        nx = i[0, 1] * q + i[0, 2] * r  # (I - diag(I)) w
        ny = i[0, 1] * p + i[1, 2] * r
        nz = i[0, 2] * p + i[1, 2] * q
        mx -= q * nz - r * ny
        my -= r * nx - p * nz
        mz -= p * ny - q * nx
    mx -= q * h_r  # -w x (h_r e_z)
    my += p * h_r
    inv = af.inertia_inv
    return (inv[0, 0] * mx + inv[0, 1] * my + inv[0, 2] * mz,
            inv[1, 0] * mx + inv[1, 1] * my + inv[1, 2] * mz,
            inv[2, 0] * mx + inv[2, 1] * my + inv[2, 2] * mz)
