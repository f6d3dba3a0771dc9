"""The plant: equilibrium, NED/FRD signs, RK4 against scipy, fidelities agree, perturbations."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from contracts.airframe import PAPER, REALISTIC, attitude_coefficients, hover_rotor_speeds
from contracts.frames import (
    body_rates_from_euler_rates,
    euler_from_quat,
    euler_rates_from_body_rates,
    quat_from_euler,
    rotation_from_quat,
)
from contracts.perturbations import Perturbations
from sitl import dynamics
from sitl.plant import Plant
from tests.airframes import PAPER_NUMBERS, REALISTIC_NUMBERS, plus_airframe

FIDELITIES = ("paper", "rigid-body")


def hover_fraction(af=PAPER) -> np.ndarray:
    return hover_rotor_speeds(af) / af.max_rad_s


@pytest.mark.parametrize("fidelity", FIDELITIES)
@pytest.mark.parametrize("af", [PAPER, REALISTIC], ids=["paper", "realistic"])
def test_hover_is_an_equilibrium(fidelity: str, af) -> None:
    plant = Plant(
        af, fidelity, position_ned_m=(0.0, 0.0, -1.0), rotor_rad_s=hover_rotor_speeds(af)
    )
    plant.set_motor_commands(hover_fraction(af))
    plant.advance(5.0)
    state = plant.state()
    assert np.allclose(state.position_ned_m, [0.0, 0.0, -1.0], atol=1e-9)
    assert np.allclose(state.velocity_ned_mps, 0.0, atol=1e-9)
    assert np.allclose(state.euler_rad, 0.0, atol=1e-12)


def _accelerate(fidelity: str, euler, commands) -> np.ndarray:
    plant = Plant(PAPER, fidelity, euler_rad=euler, rotor_rad_s=hover_rotor_speeds(PAPER))
    plant.set_motor_commands(np.asarray(commands))
    plant.advance(0.05)
    return plant.state()


@pytest.mark.parametrize("fidelity", FIDELITIES)
def test_positive_pitch_accelerates_toward_minus_x(fidelity: str) -> None:
    s = _accelerate(fidelity, (0.0, 0.2, 0.0), hover_fraction())
    assert s.velocity_ned_mps[0] < -0.05
    assert abs(s.velocity_ned_mps[1]) < 1e-9


@pytest.mark.parametrize("fidelity", FIDELITIES)
def test_positive_roll_accelerates_toward_plus_y(fidelity: str) -> None:
    s = _accelerate(fidelity, (0.2, 0.0, 0.0), hover_fraction())
    assert s.velocity_ned_mps[1] > 0.05


@pytest.mark.parametrize("fidelity", FIDELITIES)
def test_more_thrust_climbs(fidelity: str) -> None:
    s = _accelerate(fidelity, (0.0, 0.0, 0.0), 1.1 * hover_fraction())
    assert s.velocity_ned_mps[2] < -0.05  # NED: up is -z
    s = _accelerate(fidelity, (0.0, 0.0, 0.0), 0.9 * hover_fraction())
    assert s.velocity_ned_mps[2] > 0.05


@pytest.mark.parametrize("fidelity", FIDELITIES)
def test_rotor_layout_signs(fidelity: str) -> None:
    h = hover_fraction()[0]
    # Rotor 4 (left) faster than rotor 2 (right): positive roll rate (right wing down).
    s = _accelerate(fidelity, (0, 0, 0), [h, h * 0.99, h, h * 1.01])
    assert s.body_rate_rad_s[0] > 0
    # Rotor 1 (front) faster than rotor 3 (rear): nose up, positive pitch rate.
    s = _accelerate(fidelity, (0, 0, 0), [h * 1.01, h, h * 0.99, h])
    assert s.body_rate_rad_s[1] > 0
    # Rotors 2, 4 faster (they spin along -z_b, reaction along +z_b): positive yaw rate.
    s = _accelerate(fidelity, (0, 0, 0), [h * 0.99, h * 1.01, h * 0.99, h * 1.01])
    assert s.body_rate_rad_s[2] > 0


# Three distinct inertias, so every a_i of the paper's model is non-zero (on PAPER,
# Ixx = Iyy makes a5 = 0), and a rotor inertia large enough for the gyroscopic terms to
# be of the same order as the others.
ASYMMETRIC_NUMBERS = PAPER_NUMBERS._replace(ixx_kgm2=0.15, iyy_kgm2=0.21, izz_kgm2=0.09)
ASYMMETRIC = plus_airframe(ASYMMETRIC_NUMBERS)
NUMBERS = {id(PAPER): PAPER_NUMBERS, id(ASYMMETRIC): ASYMMETRIC_NUMBERS}
RATES = (0.7, -1.3, 0.9)  # phi', theta', psi' (paper) or p, q, r (rigid body at level)


def _rotor_speeds(af) -> np.ndarray:
    w = hover_rotor_speeds(af)[0]
    return np.array([w + 15.0, w - 5.0, w + 8.0, w + 3.0])  # W_r = 15 + 5 + 8 - 3 = 25


def _paper_attitude_acceleration_by_hand(af, rates, rotors) -> tuple[list, list, list]:
    """The paper model (docs/mathematics.md) written out: phi'', theta'', psi'' term by term."""
    n = NUMBERS[id(af)]
    ixx, iyy, izz, jr = n.ixx_kgm2, n.iyy_kgm2, n.izz_kgm2, n.rotor_inertia_kgm2
    arm, b, d = n.arm_m, n.thrust_coeff_ns2, n.drag_coeff_nms2
    p, q, r = rates
    w1, w2, w3, w4 = rotors
    w_r = w1 - w2 + w3 - w4
    u_phi = b * (w4**2 - w2**2)
    u_theta = b * (w1**2 - w3**2)
    u_psi = d * (w2**2 + w4**2 - w1**2 - w3**2)
    a1, a2 = (iyy - izz) / ixx, jr / ixx
    a3, a4 = (izz - ixx) / iyy, jr / iyy
    a5 = (ixx - iyy) / izz
    b1, b2, b3 = arm / ixx, arm / iyy, 1.0 / izz
    assert tuple(attitude_coefficients(af)) == pytest.approx((a1, a2, a3, a4, a5, b1, b2, b3),
                                                             rel=1e-15)
    return ([a1 * q * r, -a2 * q * w_r, b1 * u_phi],
            [a3 * p * r, a4 * p * w_r, b2 * u_theta],
            [a5 * p * q, b3 * u_psi])


@pytest.mark.parametrize("af", [PAPER, ASYMMETRIC], ids=["paper", "asymmetric"])
def test_paper_attitude_model_term_by_term(af) -> None:
    """phi'' = a1 theta' psi' - a2 theta' W_r + b1 U_phi, theta'' = a3 phi' psi' + a4 phi' W_r
    + b2 U_theta, psi'' = a5 phi' theta' + b3 U_psi, with every rate and W_r non-zero (the
    gyroscopic terms have opposite signs on roll and pitch)."""
    state = np.zeros(dynamics.PAPER_STATE_SIZE)
    state[6:9] = (0.2, -0.1, 0.4)  # the paper's model does not depend on the angles
    state[9:12] = RATES
    state[12:16] = _rotor_speeds(af)
    d = dynamics.paper_derivative(state, state[12:16].copy(), af, dynamics.no_disturbance())
    terms = _paper_attitude_acceleration_by_hand(af, RATES, state[12:16])
    for i, axis_terms in enumerate(terms):
        assert d[9 + i] == pytest.approx(sum(axis_terms), rel=1e-12, abs=1e-12), i
        # Every term with a non-zero coefficient moves the sum by far more than the
        # tolerance, so dropping one or flipping its sign fails.
        for term in axis_terms:
            assert term == 0.0 or abs(term) > 1e-3 * abs(d[9 + i]), (i, term)
    assert np.array_equal(d[6:9], RATES)
    if af is ASYMMETRIC:
        assert all(t != 0.0 for axis_terms in terms for t in axis_terms)


def _rigid_state(af, quat, body_rates) -> np.ndarray:
    state = np.zeros(dynamics.RIGID_STATE_SIZE)
    state[6:10] = quat
    state[10:13] = body_rates
    state[13:17] = _rotor_speeds(af)
    return state


@pytest.mark.parametrize("af", [PAPER, ASYMMETRIC], ids=["paper", "asymmetric"])
def test_rigid_body_rates_follow_newton_euler_with_the_rotor_gyroscope(af) -> None:
    """I w' = -w x I w - w x (Jr W_r e_z) + tau (vector form, any attitude), and at level
    attitude (body rates = Euler rates) the paper model's accelerations term for term."""
    dist = dynamics.no_disturbance()
    rotors = _rotor_speeds(af)
    w_r = rotors[0] - rotors[1] + rotors[2] - rotors[3]
    n = NUMBERS[id(af)]
    inertia = np.diag([n.ixx_kgm2, n.iyy_kgm2, n.izz_kgm2])
    omega = np.array(RATES)
    b, d_ = n.thrust_coeff_ns2, n.drag_coeff_nms2
    tau = np.array([n.arm_m * b * (rotors[3] ** 2 - rotors[1] ** 2),
                    n.arm_m * b * (rotors[0] ** 2 - rotors[2] ** 2),
                    d_ * (rotors[1] ** 2 + rotors[3] ** 2 - rotors[0] ** 2 - rotors[2] ** 2)])
    gyro = -np.cross(omega, n.rotor_inertia_kgm2 * w_r * np.array([0.0, 0.0, 1.0]))
    expected = np.linalg.solve(inertia, -np.cross(omega, inertia @ omega) + gyro + tau)
    model = af
    for quat in (np.array([1.0, 0.0, 0.0, 0.0]), quat_from_euler(0.3, -0.2, 1.1)):
        state = _rigid_state(af, quat, omega)
        d = dynamics.rigid_body_derivative(state, rotors.copy(), model, dist)
        np.testing.assert_allclose(d[10:13], expected, rtol=1e-12, atol=1e-12)
    # Level: the same numbers as the paper's model with Euler rates = body rates.
    level = dynamics.rigid_body_derivative(_rigid_state(af, np.array([1.0, 0, 0, 0]), omega),
                                           rotors.copy(), model, dist)
    terms = _paper_attitude_acceleration_by_hand(af, RATES, rotors)
    np.testing.assert_allclose(level[10:13], [sum(t) for t in terms], rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("fidelity", FIDELITIES)
def test_gyroscopic_terms_have_opposite_signs_on_roll_and_pitch(fidelity: str) -> None:
    """The rotor gyroscope alone (the derivative with Jr minus the one with Jr = 0):
    -a2 theta' W_r on roll, +a4 phi' W_r on pitch, nothing on yaw, on both plants."""
    af = ASYMMETRIC
    n = ASYMMETRIC_NUMBERS
    no_jr = plus_airframe(n._replace(rotor_inertia_kgm2=0.0))
    rotors = _rotor_speeds(af)
    w_r = 25.0
    p, q, _r = RATES
    if fidelity == "paper":
        state = np.zeros(dynamics.PAPER_STATE_SIZE)
        state[9:12] = RATES
        state[12:16] = rotors
        accel = slice(9, 12)
        derivative = dynamics.paper_derivative
    else:
        state = _rigid_state(af, np.array([1.0, 0.0, 0.0, 0.0]), RATES)
        accel = slice(10, 13)
        derivative = dynamics.rigid_body_derivative
    dist = dynamics.no_disturbance()
    gyro = (derivative(state, rotors.copy(), af, dist)[accel]
            - derivative(state, rotors.copy(), no_jr, dist)[accel])
    jr = n.rotor_inertia_kgm2
    expected = [-jr / n.ixx_kgm2 * q * w_r, jr / n.iyy_kgm2 * p * w_r, 0.0]
    np.testing.assert_allclose(gyro, expected, rtol=1e-9, atol=1e-12)
    assert gyro[0] > 0 and gyro[1] > 0  # theta' < 0, phi' > 0, W_r > 0: both push up


@pytest.mark.parametrize("fidelity", FIDELITIES)
def test_rk4_matches_scipy_reference_integration(fidelity: str) -> None:
    """The fixed-step RK4 against scipy's adaptive DOP853 on a tumbling manoeuvre."""
    code = dynamics.FIDELITIES[fidelity]
    plant = Plant(
        plus_airframe(REALISTIC_NUMBERS._replace(motor_tau_s=0.02)),
        fidelity,
        step_s=0.001,
        euler_rad=(0.3, -0.2, 0.5),
        rotor_rad_s=600.0,
    )
    plant.set_perturbations(Perturbations(wind_ned_mps=(2.0, -1.0, 0.0)))
    x0 = plant.raw_state
    cmd = np.array([0.62, 0.55, 0.58, 0.66])
    command_rad_s = cmd * REALISTIC.max_rad_s
    dist = dynamics.no_disturbance()
    dist[dynamics.DIST_WIND : dynamics.DIST_WIND + 3] = (2.0, -1.0, 0.0)

    def rhs(_t, x):
        out = np.empty_like(x)
        dynamics.derivative_into(code, x, command_rad_s, plant.model, dist, out)
        return out

    plant.set_motor_commands(cmd)
    plant.advance(0.5)
    ref = solve_ivp(rhs, (0.0, 0.5), x0, method="DOP853", rtol=1e-11, atol=1e-12).y[:, -1]
    got = plant.raw_state
    if fidelity == "rigid-body":
        ref[6:10] /= np.linalg.norm(ref[6:10])
    assert np.max(np.abs(got - ref)) < 1e-7


def test_fidelities_agree_at_small_angles() -> None:
    h = hover_fraction()
    plants = [
        Plant(PAPER, f, euler_rad=(0.01, -0.01, 0.0), rotor_rad_s=hover_rotor_speeds(PAPER))
        for f in FIDELITIES
    ]
    for p in plants:
        p.set_motor_commands(h * [1.001, 1.0, 0.999, 1.0])
        p.advance(0.5)
    a, b = (p.state() for p in plants)
    assert np.allclose(a.euler_rad, b.euler_rad, atol=2e-4)
    assert np.allclose(a.position_ned_m, b.position_ned_m, atol=1e-4)


def test_frames_round_trip() -> None:
    rng = np.random.default_rng(1)
    for _ in range(100):
        e = rng.uniform([-3, -1.5, -3], [3, 1.5, 3])
        q = quat_from_euler(*e)
        assert np.allclose(euler_from_quat(q), e, atol=1e-9)
        r = rotation_from_quat(q)
        assert np.allclose(r @ r.T, np.eye(3), atol=1e-12)
        rates = rng.normal(size=3)
        back = euler_rates_from_body_rates(
            e[0], e[1], *body_rates_from_euler_rates(e[0], e[1], *rates)
        )
        assert np.allclose(back, rates, atol=1e-9)


def test_perturbations_change_the_plant_and_are_validated() -> None:
    plant = Plant(PAPER, "rigid-body")
    plant.set_perturbations(
        Perturbations(inertia_scale=1.2, rotor_inertia_scale=1.2, mass_scale=1.1)
    )
    assert plant.model.inertia_kgm2[0, 0] == pytest.approx(0.18 * 1.2)
    assert plant.model.inertia_inv[2, 2] == pytest.approx(1 / (0.09 * 1.2))
    assert plant.model.rotor_inertia_kgm2.tolist() == pytest.approx([1.32e-3 * 1.2] * 4)
    assert plant.model.mass_kg == pytest.approx(1.32)
    plant.set_perturbations(Perturbations())
    nominal = plant.nominal_model
    assert plant.model.mass_kg == nominal.mass_kg == PAPER.mass_kg
    assert np.array_equal(plant.model.inertia_kgm2, np.diag([0.18, 0.18, 0.09]))
    for bad in (
        dict(inertia_scale=math.nan),
        dict(mass_scale=0.0),
        dict(inertia_scale=math.inf),
        dict(motor_efficiency=(1, 1, 1, 1.5)),
        dict(wind_ned_mps=(0, math.nan, 0)),
        dict(force_ned_n=(0, 0)),
    ):
        with pytest.raises(ValueError):
            Perturbations(**bad)
    with pytest.raises(ValueError, match="motor commands"):
        plant.set_motor_commands([0.5, 0.5, math.nan, 0.5])
    with pytest.raises(ValueError, match="whole number"):
        plant.advance(0.0105)


def test_motor_failure_and_external_torque_act() -> None:
    h = hover_fraction()[0]
    plant = Plant(PAPER, "rigid-body", rotor_rad_s=hover_rotor_speeds(PAPER))
    plant.set_perturbations(Perturbations(motor_efficiency=(1.0, 0.0, 1.0, 1.0)))
    plant.set_motor_commands(np.full(4, h))
    plant.advance(0.1)
    assert plant.state().body_rate_rad_s[0] > 0.1  # rotor 2 (right) out: rolls right
    plant = Plant(PAPER, "paper")
    plant.set_perturbations(Perturbations(torque_frd_nm=(0.0, 0.0, 0.09)))
    plant.advance(0.1)
    assert plant.state().euler_rate_rad_s[2] == pytest.approx(0.1, rel=1e-9)  # tau / Izz * t
