"""Controller core: mixer, sliding-mode law, Lyapunov function, command filter, parameters."""

from __future__ import annotations

import math

import numpy as np
import pytest

from autopilot.control.cascade import desired_angles
from autopilot.control.command_filter import command_filter_step
from autopilot.control.gains import ChannelGains
from autopilot.control.mixer import mix
from autopilot.control.sliding_mode import (
    TEL_EEPS,
    adaptive_channel_step,
    boundary_layer_distance,
    lyapunov,
)
from autopilot.parameters import (
    PARAMETERS,
    default_parameters,
    validate_parameters,
)
from contracts.airframe import (
    PAPER,
    airframe_by_name,
    airframe_from_spec,
    controller_inputs,
    hover_rotor_speeds,
    max_thrust_n,
    rotor_speeds,
)
from contracts.airframe_file import parse_airframe, read_airframe


def _tilted_h_frame():
    """An asymmetric H with products of inertia and the thrust command map: every part of
    the mixer that the shipped frames leave at zero is used."""
    data = {"mass_kg": 1.6,
            "inertia_kgm2": [[0.021, 0.002, -0.001], [0.002, 0.026, 0.0015],
                             [-0.001, 0.0015, 0.041]],
            "command_map": "thrust", "rotor": []}
    for x, y, spin, k in ((0.20, 0.25, "ccw", 1.2e-5), (-0.15, -0.18, "ccw", 1e-5),
                          (0.20, -0.25, "cw", 1.2e-5), (-0.15, 0.18, "cw", 1e-5)):
        data["rotor"].append({"position_m": [x, y, 0.0], "spin": spin, "thrust_coeff_ns2": k,
                              "moment_coeff_nms2": 1.6e-7, "max_rad_s": 1000.0})
    return airframe_from_spec(parse_airframe(data, "h-frame"))


FRAMES = {"paper": PAPER, "quad-x-500": airframe_by_name("quad-x-500"),
          "h-tilted": _tilted_h_frame()}


def forward(commands: np.ndarray, af=PAPER) -> tuple[float, float, float, float]:
    """(U_z, U_phi, U_theta, U_psi) the plant gets from these motor commands."""
    return controller_inputs(rotor_speeds(commands, af), np.ones(4), af)


@pytest.mark.parametrize("name", FRAMES)
def test_mixer_inverts_the_rotor_map_when_unsaturated(name) -> None:
    af = FRAMES[name]
    rng = np.random.default_rng(0)
    weight = af.mass_kg * af.gravity_mps2
    scale = 0.05 * max_thrust_n(af) * 0.2  # U_phi, U_theta [N] well inside authority
    for _ in range(200):
        wanted = (
            weight * rng.uniform(0.8, 1.3),
            rng.uniform(-scale, scale),
            rng.uniform(-scale, scale),
            rng.uniform(-0.002, 0.002) * weight,
        )
        c = mix(*wanted, af)
        assert np.all((c > 0) & (c < 1))
        assert np.allclose(forward(c, af), wanted, rtol=1e-9, atol=1e-9)


@pytest.mark.parametrize("name", FRAMES)
def test_mixer_hover(name) -> None:
    af = FRAMES[name]
    c = mix(af.mass_kg * af.gravity_mps2, 0.0, 0.0, 0.0, af)
    np.testing.assert_allclose(rotor_speeds(c, af), hover_rotor_speeds(af), rtol=1e-12)
    if name != "h-tilted":  # four alike rotors: equal commands
        assert np.ptp(c) < 1e-12


def test_max_thrust_is_where_the_first_rotor_tops_out() -> None:
    n = read_airframe("paper").rotors[0]
    assert max_thrust_n(PAPER) == pytest.approx(4 * n.thrust_coeff_ns2 * n.max_rad_s**2,
                                                rel=1e-12)
    af = FRAMES["h-tilted"]
    c = mix(max_thrust_n(af), 0.0, 0.0, 0.0, af)
    assert np.max(c) == pytest.approx(1.0, rel=1e-12) and np.min(c) < 0.95


@pytest.mark.parametrize("name", FRAMES)
def test_mixer_saturation_keeps_roll_pitch_before_thrust_and_yaw(name) -> None:
    af = FRAMES[name]
    top_thrust = max_thrust_n(af)
    arm = top_thrust / 8.0  # a roll demand of half of one rotor's thrust
    # Near full thrust with a roll demand: roll is delivered, thrust gives way, yaw is cut.
    c = mix(0.98 * top_thrust, arm, 0.0, 0.3 * arm, af)
    u_z, u_phi, u_theta, u_psi = forward(c, af)
    assert np.all((c >= 0) & (c <= 1))
    assert u_phi == pytest.approx(arm, rel=1e-9)
    assert u_theta == pytest.approx(0.0, abs=1e-9)
    unconstrained = af.mixing @ [0.98 * top_thrust, arm, 0.0, 0.0]
    if np.any(unconstrained > af.max_rad_s**2):
        assert u_z < 0.98 * top_thrust  # it gave way
    else:  # the frame has the room where this roll needs it
        assert u_z == pytest.approx(0.98 * top_thrust, rel=1e-9)
    assert abs(u_psi) < 0.3 * arm
    # A roll/pitch demand beyond authority keeps its direction (ratio), scaled down.
    c = mix(0.5 * top_thrust, 40.0 * arm, 20.0 * arm, 0.0, af)
    _, u_phi, u_theta, _ = forward(c, af)
    assert u_phi / u_theta == pytest.approx(2.0, rel=1e-9)
    assert np.min(c) == pytest.approx(0.0, abs=1e-6)  # it used the authority there is
    # At low collective roll/pitch shrink instead of the collective rising.
    low = 0.01 * top_thrust
    c = mix(low, arm, 0.0, 0.0, af)
    u_z, u_phi, _, _ = forward(c, af)
    assert u_z == pytest.approx(low, rel=1e-9)
    assert 0 < u_phi < arm


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
