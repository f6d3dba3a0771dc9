"""Quadrotor equations of motion and the fixed-step RK4 integrator (pure, numba-compiled).

Two fidelities (docs/mathematics.md):

* ``paper``: the paper's Eq. (sys), small-angle (Euler rates = body rates).
  State: position NED (0:3), velocity NED (3:6), Euler angles (6:9), Euler rates (9:12),
  rotor speeds (12:16).
* ``rigid-body``: Newton-Euler with a unit quaternion.
  State: position NED (0:3), velocity NED (3:6), quaternion body->NED (6:10),
  body rates FRD (10:13), rotor speeds (13:17).

Disturbance vector (both): external force NED [N] (0:3), external torque FRD [N m]
(3:6), wind NED [m/s] (6:9), rotor efficiency (9:13).

Both integrate a ``contracts.airframe.Airframe``: any quadrotor's geometry as its
effectiveness matrix (docs/airframes.md), so the simulator flies whatever airframe file it
is given.

The derivative's helpers are inlined into the integrator (``inline="always"``): a call
between compiled functions takes and releases a reference to every array it is given,
the airframe's ten included, each an atomic operation (numba's NRT_incref and
NRT_decref were 8 % of the simulator's CPU in a lockstep run). Inlined, the compiler
drops those pairs: a 10 ms plant step (ten RK4 steps) takes 15 us where it took 25 (the
two alternated), with the same numbers bit for bit.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from contracts.airframe import Airframe
from contracts.frames import rotation_from_quat

FIDELITY_PAPER = 0
FIDELITY_RIGID_BODY = 1
FIDELITIES = {"paper": FIDELITY_PAPER, "rigid-body": FIDELITY_RIGID_BODY}

PAPER_STATE_SIZE = 16
RIGID_STATE_SIZE = 17
PAPER_ROTOR = 12
RIGID_ROTOR = 13

DIST_FORCE = 0
DIST_TORQUE = 3
DIST_WIND = 6
DIST_EFFICIENCY = 9
DISTURBANCE_SIZE = 13


def no_disturbance() -> np.ndarray:
    dist = np.zeros(DISTURBANCE_SIZE)
    dist[DIST_EFFICIENCY:] = 1.0
    return dist


def perturbed_model(model: Airframe, mass_scale: float, inertia_scale: float,
                    rotor_inertia_scale: float) -> Airframe:
    """The model with mass, body inertia and rotor inertia scaled (perturbations). The
    autopilot's nominal fields (input gains, mixing) stay: the dynamics do not read them."""
    return model._replace(
        mass_kg=model.mass_kg * mass_scale, inertia_kgm2=model.inertia_kgm2 * inertia_scale,
        inertia_inv=model.inertia_inv / inertia_scale,
        rotor_inertia_kgm2=model.rotor_inertia_kgm2 * rotor_inertia_scale)


@njit(cache=True, inline="always")
def rotor_wrench(
    rotor_rad_s: np.ndarray, efficiency: np.ndarray, model: Airframe
) -> tuple[float, float, float, float, float]:
    """Collective thrust [N], roll, pitch, yaw torque [N m] from the rotor speeds through
    the effectiveness matrix, and the rotors' angular momentum h_r = sum Jr_i s_i W_i along
    +z_b. ``efficiency`` scales each rotor's thrust and drag (1 healthy, 0 failed)."""
    e = model.effectiveness
    u_z = tau_x = tau_y = tau_z = h_r = 0.0
    for i in range(4):
        w2 = efficiency[i] * rotor_rad_s[i] * rotor_rad_s[i]
        u_z += e[0, i] * w2
        tau_x += e[1, i] * w2
        tau_y += e[2, i] * w2
        tau_z += e[3, i] * w2
        h_r += model.rotor_inertia_kgm2[i] * model.spin[i] * rotor_rad_s[i]
    return u_z, tau_x, tau_y, tau_z, h_r


@njit(cache=True, inline="always")
def _rotor_derivative(
    rotor_rad_s: np.ndarray, command_rad_s: np.ndarray, model: Airframe, out: np.ndarray
) -> None:
    """First-order rotor lag; with tau = 0 the speeds are set, not integrated."""
    for i in range(4):
        tau = model.time_constant_s[i]
        out[i] = (command_rad_s[i] - rotor_rad_s[i]) / tau if tau > 0 else 0.0


@njit(cache=True)
def paper_derivative(
    state: np.ndarray, command_rad_s: np.ndarray, af: Airframe, dist: np.ndarray
) -> np.ndarray:
    """The paper's Eq. (sys) with the signs of docs/mathematics.md, plus disturbances:
    phi'' = f_phi + tau_x / Ixx etc., the diagonal of the inertia matrix (the paper's
    model has no products of inertia), J_r W_r generalised to the rotors' momentum h_r."""
    out = np.zeros(PAPER_STATE_SIZE)
    _paper_derivative_into(state, command_rad_s, af, dist, out)
    return out


@njit(cache=True, inline="always")
def _paper_derivative_into(
    state: np.ndarray, command_rad_s: np.ndarray, af: Airframe, dist: np.ndarray,
    out: np.ndarray,
) -> None:
    """:func:`paper_derivative` into ``out`` (every element written)."""
    rotor = state[PAPER_ROTOR:PAPER_ROTOR + 4]
    u_z, tau_x, tau_y, tau_z, h_r = rotor_wrench(rotor, dist[DIST_EFFICIENCY:], af)
    phi, theta, psi = state[6], state[7], state[8]
    phi_dot, theta_dot, psi_dot = state[9], state[10], state[11]
    ixx, iyy, izz = af.inertia_kgm2[0, 0], af.inertia_kgm2[1, 1], af.inertia_kgm2[2, 2]
    f_phi = (iyy - izz) / ixx * theta_dot * psi_dot - h_r / ixx * theta_dot
    f_theta = (izz - ixx) / iyy * phi_dot * psi_dot + h_r / iyy * phi_dot
    f_psi = (ixx - iyy) / izz * phi_dot * theta_dot
    m = af.mass_kg
    cphi, sphi = math.cos(phi), math.sin(phi)
    cth, sth = math.cos(theta), math.sin(theta)
    cpsi, spsi = math.cos(psi), math.sin(psi)
    out[0:3] = state[3:6]
    k = af.linear_drag_nspm
    out[3] = (
        -(u_z / m) * (cphi * sth * cpsi + sphi * spsi)
        + (dist[DIST_FORCE] - k * (state[3] - dist[DIST_WIND])) / m
    )
    out[4] = (
        -(u_z / m) * (cphi * sth * spsi - sphi * cpsi)
        + (dist[DIST_FORCE + 1] - k * (state[4] - dist[DIST_WIND + 1])) / m
    )
    out[5] = (
        af.gravity_mps2
        - (u_z / m) * cphi * cth
        + (dist[DIST_FORCE + 2] - k * (state[5] - dist[DIST_WIND + 2])) / m
    )
    out[6:9] = state[9:12]
    out[9] = f_phi + (tau_x + dist[DIST_TORQUE]) / ixx
    out[10] = f_theta + (tau_y + dist[DIST_TORQUE + 1]) / iyy
    out[11] = f_psi + (tau_z + dist[DIST_TORQUE + 2]) / izz
    _rotor_derivative(rotor, command_rad_s, af, out[PAPER_ROTOR:])


@njit(cache=True)
def rigid_body_derivative(
    state: np.ndarray, command_rad_s: np.ndarray, af: Airframe, dist: np.ndarray
) -> np.ndarray:
    """Newton-Euler: I w' = -w x I w + tau + tau_gyro, v' = g e_z + R(-U_z e_z)/m + ...
    with the full inertia matrix; tau_gyro = -w x h_r e_z."""
    out = np.zeros(RIGID_STATE_SIZE)
    _rigid_body_derivative_into(state, command_rad_s, af, dist, out)
    return out


@njit(cache=True, inline="always")
def _rigid_body_derivative_into(
    state: np.ndarray, command_rad_s: np.ndarray, af: Airframe, dist: np.ndarray,
    out: np.ndarray,
) -> None:
    """:func:`rigid_body_derivative` into ``out`` (every element written)."""
    rotor = state[RIGID_ROTOR:RIGID_ROTOR + 4]
    u_z, tau_x, tau_y, tau_z, h_r = rotor_wrench(rotor, dist[DIST_EFFICIENCY:], af)
    q = state[6:10]
    p, qr, r = state[10], state[11], state[12]
    rot = rotation_from_quat(q)
    m = af.mass_kg
    k = af.linear_drag_nspm
    out[0:3] = state[3:6]
    for i in range(3):
        out[3 + i] = (
            -rot[i, 2] * u_z / m
            + (dist[DIST_FORCE + i] - k * (state[3 + i] - dist[DIST_WIND + i])) / m
        )
    out[5] += af.gravity_mps2
    # Quaternion kinematics q' = 1/2 q (x) [0, w].
    out[6] = 0.5 * (-q[1] * p - q[2] * qr - q[3] * r)
    out[7] = 0.5 * (q[0] * p + q[2] * r - q[3] * qr)
    out[8] = 0.5 * (q[0] * qr - q[1] * r + q[3] * p)
    out[9] = 0.5 * (q[0] * r + q[1] * qr - q[2] * p)
    inertia = af.inertia_kgm2
    hx = inertia[0, 0] * p + inertia[0, 1] * qr + inertia[0, 2] * r  # I w
    hy = inertia[1, 0] * p + inertia[1, 1] * qr + inertia[1, 2] * r
    hz = inertia[2, 0] * p + inertia[2, 1] * qr + inertia[2, 2] * r + h_r  # + rotors
    mx = tau_x + dist[DIST_TORQUE] - (qr * hz - r * hy)  # tau - w x (I w + h_r e_z)
    my = tau_y + dist[DIST_TORQUE + 1] - (r * hx - p * hz)
    mz = tau_z + dist[DIST_TORQUE + 2] - (p * hy - qr * hx)
    inv = af.inertia_inv
    out[10] = inv[0, 0] * mx + inv[0, 1] * my + inv[0, 2] * mz
    out[11] = inv[1, 0] * mx + inv[1, 1] * my + inv[1, 2] * mz
    out[12] = inv[2, 0] * mx + inv[2, 1] * my + inv[2, 2] * mz
    _rotor_derivative(rotor, command_rad_s, af, out[RIGID_ROTOR:])


@njit(cache=True, inline="always")
def derivative_into(
    fidelity: int, state: np.ndarray, command_rad_s: np.ndarray, af: Airframe,
    dist: np.ndarray, out: np.ndarray,
) -> None:
    """The state derivative of either plant into ``out`` (what RK4 integrates)."""
    if fidelity == FIDELITY_PAPER:
        _paper_derivative_into(state, command_rad_s, af, dist, out)
    else:
        _rigid_body_derivative_into(state, command_rad_s, af, dist, out)


@njit(cache=True)
def rk4_integrate(
    fidelity: int,
    state: np.ndarray,
    command_rad_s: np.ndarray,
    af: Airframe,
    dist: np.ndarray,
    step_s: float,
    n_steps: int,
    ground_contact: bool = False,
) -> np.ndarray:
    """Advance ``n_steps`` fixed RK4 steps with the rotor command held (zero-order hold).

    With ``ground_contact`` the plane z = 0 (NED) is the ground: see :func:`rest_on_ground`.

    The stages go into arrays made once per call, element by element in the order of
    ``x + 0.5 * step_s * k1`` ... ``x += (step_s / 6.0) * (k1 + 2 k2 + 2 k3 + k4)``
    (the same numbers as those array expressions, without their temporary arrays).
    """
    x = state.copy()
    n = x.size
    k1, k2, k3, k4, stage = np.empty(n), np.empty(n), np.empty(n), np.empty(n), np.empty(n)
    half, sixth = 0.5 * step_s, step_s / 6.0
    rotor_at = PAPER_ROTOR if fidelity == FIDELITY_PAPER else RIGID_ROTOR
    for _ in range(n_steps):
        for i in range(4):
            if af.time_constant_s[i] <= 0.0:
                x[rotor_at + i] = command_rad_s[i]
        derivative_into(fidelity, x, command_rad_s, af, dist, k1)
        for i in range(n):
            stage[i] = x[i] + half * k1[i]
        derivative_into(fidelity, stage, command_rad_s, af, dist, k2)
        for i in range(n):
            stage[i] = x[i] + half * k2[i]
        derivative_into(fidelity, stage, command_rad_s, af, dist, k3)
        for i in range(n):
            stage[i] = x[i] + step_s * k3[i]
        derivative_into(fidelity, stage, command_rad_s, af, dist, k4)
        for i in range(n):
            x[i] += sixth * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])
        if fidelity == FIDELITY_RIGID_BODY:
            x[6:10] /= math.sqrt(x[6] ** 2 + x[7] ** 2 + x[8] ** 2 + x[9] ** 2)
        if ground_contact and x[2] > 0.0:
            rest_on_ground(fidelity, x)
    return x


@njit(cache=True, inline="always")
def rest_on_ground(fidelity: int, x: np.ndarray) -> None:
    """A vehicle pushed below z = 0 sits level on the ground, at rest, keeping its yaw.

    A contact model for take-off and landing, not for crashes: the plant does not model
    tip-over or bounce. Thrust above weight lifts it off on the next step.
    """
    x[2] = 0.0
    x[3:6] = 0.0
    if fidelity == FIDELITY_PAPER:
        x[6] = 0.0
        x[7] = 0.0
        x[9:12] = 0.0
    else:
        w, qx, qy, qz = x[6], x[7], x[8], x[9]
        yaw = math.atan2(2.0 * (w * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))
        x[6] = math.cos(0.5 * yaw)
        x[7] = 0.0
        x[8] = 0.0
        x[9] = math.sin(0.5 * yaw)
        x[10:13] = 0.0
