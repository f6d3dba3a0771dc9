"""The plant: equilibrium, NED/FRD signs, RK4 against scipy, fidelities agree, perturbations."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from contracts.airframe import PAPER, REALISTIC, hover_rotor_speed_rad_s
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

FIDELITIES = ("paper", "rigid-body")


def hover_fraction(af=PAPER) -> float:
    return hover_rotor_speed_rad_s(af) / af.rotor_max_rad_s


@pytest.mark.parametrize("fidelity", FIDELITIES)
@pytest.mark.parametrize("af", [PAPER, REALISTIC], ids=["paper", "realistic"])
def test_hover_is_an_equilibrium(fidelity: str, af) -> None:
    plant = Plant(
        af, fidelity, position_ned_m=(0.0, 0.0, -1.0), rotor_rad_s=hover_rotor_speed_rad_s(af)
    )
    plant.set_motor_commands(np.full(4, hover_fraction(af)))
    plant.advance(5.0)
    state = plant.state()
    assert np.allclose(state.position_ned_m, [0.0, 0.0, -1.0], atol=1e-9)
    assert np.allclose(state.velocity_ned_mps, 0.0, atol=1e-9)
    assert np.allclose(state.euler_rad, 0.0, atol=1e-12)


def _accelerate(fidelity: str, euler, commands) -> np.ndarray:
    plant = Plant(PAPER, fidelity, euler_rad=euler, rotor_rad_s=hover_rotor_speed_rad_s(PAPER))
    plant.set_motor_commands(np.asarray(commands))
    plant.advance(0.05)
    return plant.state()


@pytest.mark.parametrize("fidelity", FIDELITIES)
def test_positive_pitch_accelerates_toward_minus_x(fidelity: str) -> None:
    s = _accelerate(fidelity, (0.0, 0.2, 0.0), np.full(4, hover_fraction()))
    assert s.velocity_ned_mps[0] < -0.05
    assert abs(s.velocity_ned_mps[1]) < 1e-9


@pytest.mark.parametrize("fidelity", FIDELITIES)
def test_positive_roll_accelerates_toward_plus_y(fidelity: str) -> None:
    s = _accelerate(fidelity, (0.2, 0.0, 0.0), np.full(4, hover_fraction()))
    assert s.velocity_ned_mps[1] > 0.05


@pytest.mark.parametrize("fidelity", FIDELITIES)
def test_more_thrust_climbs(fidelity: str) -> None:
    s = _accelerate(fidelity, (0.0, 0.0, 0.0), np.full(4, 1.1 * hover_fraction()))
    assert s.velocity_ned_mps[2] < -0.05  # NED: up is -z
    s = _accelerate(fidelity, (0.0, 0.0, 0.0), np.full(4, 0.9 * hover_fraction()))
    assert s.velocity_ned_mps[2] > 0.05


@pytest.mark.parametrize("fidelity", FIDELITIES)
def test_rotor_layout_signs(fidelity: str) -> None:
    h = hover_fraction()
    # Rotor 4 (left) faster than rotor 2 (right): positive roll rate (right wing down).
    s = _accelerate(fidelity, (0, 0, 0), [h, h * 0.99, h, h * 1.01])
    assert s.body_rate_rad_s[0] > 0
    # Rotor 1 (front) faster than rotor 3 (rear): nose up, positive pitch rate.
    s = _accelerate(fidelity, (0, 0, 0), [h * 1.01, h, h * 0.99, h])
    assert s.body_rate_rad_s[1] > 0
    # Rotors 2, 4 faster (they spin along -z_b, reaction along +z_b): positive yaw rate.
    s = _accelerate(fidelity, (0, 0, 0), [h * 0.99, h * 1.01, h * 0.99, h * 1.01])
    assert s.body_rate_rad_s[2] > 0


def test_gyroscopic_terms_have_opposite_signs_on_roll_and_pitch() -> None:
    state = np.zeros(dynamics.PAPER_STATE_SIZE)
    state[9] = 1.0  # phi'
    state[10] = 1.0  # theta'
    w = hover_rotor_speed_rad_s(PAPER)
    state[12:16] = [w + 10, w, w + 10, w]  # W_r = +20 rad/s
    d = dynamics.paper_derivative(state, state[12:16].copy(), PAPER, dynamics.no_disturbance())
    a2 = PAPER.rotor_inertia_kgm2 / PAPER.ixx_kgm2
    a4 = PAPER.rotor_inertia_kgm2 / PAPER.iyy_kgm2
    a1 = (PAPER.iyy_kgm2 - PAPER.izz_kgm2) / PAPER.ixx_kgm2
    # phi'' = a1 theta' psi' - a2 theta' W_r (+ b1 U_phi = 0), theta'' = ... + a4 phi' W_r
    assert d[9] == pytest.approx(a1 * 0.0 - a2 * 1.0 * 20.0, rel=1e-12)
    assert d[10] == pytest.approx(a4 * 1.0 * 20.0, rel=1e-12)


@pytest.mark.parametrize("fidelity", FIDELITIES)
def test_rk4_matches_scipy_reference_integration(fidelity: str) -> None:
    """The fixed-step RK4 against scipy's adaptive DOP853 on a tumbling manoeuvre."""
    code = dynamics.FIDELITIES[fidelity]
    plant = Plant(
        REALISTIC._replace(motor_tau_s=0.02),
        fidelity,
        step_s=0.001,
        euler_rad=(0.3, -0.2, 0.5),
        rotor_rad_s=600.0,
    )
    plant.set_perturbations(Perturbations(wind_ned_mps=(2.0, -1.0, 0.0)))
    x0 = plant.raw_state
    cmd = np.array([0.62, 0.55, 0.58, 0.66])
    command_rad_s = cmd * REALISTIC.rotor_max_rad_s
    dist = dynamics.no_disturbance()
    dist[dynamics.DIST_WIND : dynamics.DIST_WIND + 3] = (2.0, -1.0, 0.0)

    def rhs(_t, x):
        return dynamics._derivative(code, x, command_rad_s, plant.airframe, dist)

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
        Plant(PAPER, f, euler_rad=(0.01, -0.01, 0.0), rotor_rad_s=hover_rotor_speed_rad_s(PAPER))
        for f in FIDELITIES
    ]
    for p in plants:
        p.set_motor_commands([h * 1.001, h, h * 0.999, h])
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
    assert plant.airframe.ixx_kgm2 == pytest.approx(0.18 * 1.2)
    assert plant.airframe.rotor_inertia_kgm2 == pytest.approx(1.32e-3 * 1.2)
    assert plant.airframe.mass_kg == pytest.approx(1.32)
    plant.set_perturbations(Perturbations())
    assert plant.airframe == PAPER
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
    h = hover_fraction()
    plant = Plant(PAPER, "rigid-body", rotor_rad_s=hover_rotor_speed_rad_s(PAPER))
    plant.set_perturbations(Perturbations(motor_efficiency=(1.0, 0.0, 1.0, 1.0)))
    plant.set_motor_commands(np.full(4, h))
    plant.advance(0.1)
    assert plant.state().body_rate_rad_s[0] > 0.1  # rotor 2 (right) out: rolls right
    plant = Plant(PAPER, "paper")
    plant.set_perturbations(Perturbations(torque_frd_nm=(0.0, 0.0, 0.09)))
    plant.advance(0.1)
    assert plant.state().euler_rate_rad_s[2] == pytest.approx(0.1, rel=1e-9)  # tau / Izz * t
