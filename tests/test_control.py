"""Controller core: mixer, sliding-mode law, Lyapunov function, command filter, parameters."""

from __future__ import annotations

import math

import numpy as np
import pytest

from autopilot.control.cascade import desired_angles
from autopilot.control.command_filter import command_filter_step
from autopilot.control.mixer import mix
from autopilot.control.parameters import (
    PARAMETERS,
    ChannelGains,
    default_parameters,
    validate_parameters,
)
from autopilot.control.sliding_mode import (
    TEL_EEPS,
    adaptive_channel_step,
    boundary_layer_distance,
    lyapunov,
)
from contracts.airframe import PAPER, hover_rotor_speed_rad_s
from sitl.dynamics import rotor_forces


def forward(commands: np.ndarray) -> tuple[float, float, float, float]:
    u_z, u_phi, u_theta, u_psi, _ = rotor_forces(commands * PAPER.rotor_max_rad_s, np.ones(4),
                                                 PAPER)
    return u_z, u_phi, u_theta, u_psi


def test_mixer_inverts_the_rotor_map_when_unsaturated() -> None:
    rng = np.random.default_rng(0)
    weight = PAPER.mass_kg * PAPER.gravity_mps2
    for _ in range(200):
        wanted = (
            weight * rng.uniform(0.6, 1.6),
            rng.uniform(-2, 2),
            rng.uniform(-2, 2),
            rng.uniform(-0.05, 0.05),
        )
        c = mix(*wanted, PAPER)
        assert np.all((c > 0) & (c < 1))
        assert np.allclose(forward(c), wanted, rtol=1e-9, atol=1e-9)


def test_mixer_hover() -> None:
    c = mix(PAPER.mass_kg * PAPER.gravity_mps2, 0.0, 0.0, 0.0, PAPER)
    assert np.allclose(c, hover_rotor_speed_rad_s(PAPER) / PAPER.rotor_max_rad_s)


def test_mixer_saturation_keeps_roll_pitch_before_thrust_and_yaw() -> None:
    top_thrust = 4 * PAPER.thrust_coeff_ns2 * PAPER.rotor_max_rad_s**2
    # Near full thrust with a roll demand: roll is delivered, thrust gives way, yaw is cut.
    c = mix(0.98 * top_thrust, 3.0, 0.0, 0.3, PAPER)
    u_z, u_phi, u_theta, u_psi = forward(c)
    assert np.all((c >= 0) & (c <= 1))
    assert u_phi == pytest.approx(3.0, rel=1e-9)
    assert u_theta == pytest.approx(0.0, abs=1e-9)
    assert u_z < 0.98 * top_thrust
    assert abs(u_psi) < 0.3
    # A roll/pitch demand beyond authority keeps its direction (ratio), scaled down.
    c = mix(0.5 * top_thrust, 40.0, 20.0, 0.0, PAPER)
    _, u_phi, u_theta, _ = forward(c)
    assert u_phi / u_theta == pytest.approx(2.0, rel=1e-9)
    # At low collective roll/pitch shrink instead of the collective rising.
    c = mix(1.0, 5.0, 0.0, 0.0, PAPER)
    u_z, u_phi, _, _ = forward(c)
    assert u_z == pytest.approx(1.0, rel=1e-9)
    assert 0 < u_phi < 5.0


def test_boundary_layer_distance() -> None:
    assert boundary_layer_distance(0.005, 0.01) == 0.0
    assert boundary_layer_distance(0.03, 0.01) == pytest.approx(0.02)
    assert boundary_layer_distance(-0.03, 0.01) == pytest.approx(-0.02)


def test_desired_angles_invert_the_thrust_direction() -> None:
    rng = np.random.default_rng(3)
    for _ in range(100):
        phi, theta, psi = rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5), rng.uniform(-3, 3)
        u_x = math.cos(phi) * math.sin(theta) * math.cos(psi) + math.sin(phi) * math.sin(psi)
        u_y = math.cos(phi) * math.sin(theta) * math.sin(psi) - math.sin(phi) * math.cos(psi)
        assert np.allclose(desired_angles(u_x, u_y, psi, 1.4), (phi, theta), atol=1e-12)
    assert desired_angles(0.0, -0.9, 0.0, 0.3) == pytest.approx((0.3, 0.0))


def test_desired_angles_limit_the_total_tilt_or_each_axis() -> None:
    """Diagonal: per-axis clipping lets the tilt reach acos(cos^2 0.3) = 0.421 rad; the
    total limit keeps it at 0.3 rad and keeps the direction (45 deg)."""
    phi, theta = desired_angles(0.6, -0.6, 0.0, 0.3)
    assert (phi, theta) == pytest.approx((0.3, 0.3))
    per_axis_tilt = math.acos(math.cos(0.3) ** 2)
    assert math.acos(math.cos(phi) * math.cos(theta)) == pytest.approx(per_axis_tilt)
    phi, theta = desired_angles(0.6, -0.6, 0.0, 0.3, True)
    assert math.acos(math.cos(phi) * math.cos(theta)) == pytest.approx(0.3, abs=1e-12)
    u_x = math.cos(phi) * math.sin(theta)
    u_y = -math.sin(phi)
    assert math.atan2(u_y, u_x) == pytest.approx(math.atan2(-0.6, 0.6), abs=1e-12)
    assert desired_angles(0.1, 0.05, 0.3, 0.3, True) == desired_angles(0.1, 0.05, 0.3, 0.3)


def test_command_filter_respects_its_limits_and_converges() -> None:
    state = np.zeros(2)
    rates, accs = [], []
    for _ in range(300):
        x, r, a = command_filter_step(state, 0.5, 0.01, 10.0, 1.0, 2.0, 8.0)
        rates.append(r)
        accs.append(a)
    assert max(abs(r) for r in rates) <= 2.0
    assert max(abs(a) for a in accs) <= 8.0
    assert x == pytest.approx(0.5, abs=1e-4)


def _gains(eta_f: float = 2.0, eta_g: float = 0.5) -> ChannelGains:
    return ChannelGains(
        lam=4.0, gam=5.0, eps=0.02, eta_f=eta_f, eta_g=eta_g, w_f=0.1, w_g=0.1, g0=0.5, g_max=10.0
    )


def test_lyapunov_function_does_not_increase_on_a_matched_plant() -> None:
    """y'' = theta*^T phi(y, y') + g v with the same basis as the controller (docs/mathematics.md).

    Outside the boundary layer V = e_eps^2/2 + ... must not increase (up to the O(T^2)
    of the discrete update); inside it V is constant because adaptation stops.
    """
    rng = np.random.default_rng(7)
    theta_true = np.array([-1.5, 0.8, 2.0])
    g_true = 2.0

    def basis(y: float, yd: float) -> np.ndarray:
        return np.array([math.sin(y), yd, 1.0])

    gains = _gains()
    period = 1e-4
    theta_f = theta_true + rng.normal(scale=1.0, size=3)
    theta_g = 1.2
    box = np.full(3, 1e6)
    scale = np.ones(3)
    y, y_dot = 1.0, 0.0
    tel = np.zeros(10)
    values = []
    for k in range(40000):
        t = k * period
        yd, yd_dot, yd_ddot = math.sin(t), math.cos(t), -math.sin(t)
        phi = basis(y, y_dot)
        theta_before, g_before = theta_f.copy(), theta_g
        v, theta_g = adaptive_channel_step(
            y,
            y_dot,
            yd,
            yd_dot,
            yd_ddot,
            phi,
            theta_f,
            -box,
            box,
            scale,
            0.0,
            theta_g,
            gains,
            period,
            tel,
        )
        values.append(
            lyapunov(
                tel[TEL_EEPS],
                theta_before - theta_true,
                g_before - g_true,
                gains.eta_f,
                scale,
                gains.eta_g,
            )
        )
        # Exact-enough plant step (semi-implicit Euler at 1e-4 s with the held input).
        y_ddot = theta_true @ basis(y, y_dot) + g_true * v
        y_dot += period * y_ddot
        y += period * y_dot
    values = np.array(values)
    assert values[0] > 0.1  # the test starts far from the surface
    increases = np.diff(values)
    assert increases.max() <= 1e-6 * values[0]
    assert values[-1] < 0.5 * values[0]


def test_parameters_table_is_valid_and_checked() -> None:
    params = default_parameters()
    assert len(params) == len(PARAMETERS)
    for spec in PARAMETERS:
        assert spec.minimum <= spec.default <= spec.maximum, spec.name
        assert len(spec.name) <= 16
    assert validate_parameters({"ATT_LAM": 5})["ATT_LAM"] == 5.0
    for bad, match in (
        ({"NOPE": 1.0}, "unknown"),
        ({"ATT_LAM": math.nan}, "finite"),
        ({"ATT_LAM": math.inf}, "finite"),
        ({"ATT_LAM": -1.0}, "in \\["),
        ({"ATT_LAM": "x"}, "number"),
    ):
        with pytest.raises(ValueError, match=match):
            validate_parameters(bad)
