"""The indirect adaptive fuzzy sliding-mode law (docs/mathematics.md, the controller), one
equation a function.

For a channel y'' = f(x) + g v with e = y_d - y:

    e     = wrap(y_d - y) for angles   (contracts.frames.wrap_pi)
    e_s   = e' + lam e                 sliding_surface
    e_eps = e_s - eps sat(e_s / eps)   boundary_layer_distance
    u_eq  = (-f^ + y_d'' + gam e_eps + lam e') / g^          equivalent_control
    u_s   = (1/g0) (W_f + W_g |u_eq|) sat(e_s / eps)         switching_control
    theta_f' = -eta_f phi_f e_eps,  theta_g' = -eta_g e_eps u_eq   (projected)

All compiled with numba: the controller runs them every control period.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from autopilot.control.gains import ChannelGains
from contracts.frames import wrap_pi
from contracts.vectors import CHANNEL_INTERNALS


@njit(cache=True)
def sat(value: float) -> float:
    """Unit saturation, the smooth stand-in for sgn inside the boundary layer."""
    return max(-1.0, min(1.0, value))


@njit(cache=True)
def sliding_surface(e: float, e_dot: float, lam: float) -> float:
    return e_dot + lam * e


@njit(cache=True)
def boundary_layer_distance(e_s: float, eps: float) -> float:
    """Zero inside the layer |e_s| <= eps, the distance to it outside."""
    return e_s - eps * sat(e_s / eps)


@njit(cache=True)
def equivalent_control(
    f_hat: float, g_hat: float, yd_ddot: float, e_eps: float, e_dot: float, gains: ChannelGains
) -> float:
    return (-f_hat + yd_ddot + gains.gam * e_eps + gains.lam * e_dot) / g_hat


@njit(cache=True)
def switching_control(u_eq: float, e_s: float, gains: ChannelGains) -> float:
    return (gains.w_f + gains.w_g * abs(u_eq)) / gains.g0 * sat(e_s / gains.eps)


@njit(cache=True)
def adapt_theta_f(
    theta_f: np.ndarray,
    phi_f: np.ndarray,
    e_eps: float,
    theta_min: np.ndarray,
    theta_max: np.ndarray,
    eta_f: float,
    eta_scale: np.ndarray,
    period_s: float,
) -> None:
    """theta_f += T (-eta_f Gamma phi_f e_eps), projected onto [theta_min, theta_max].

    Gamma = diag(eta_scale) normalises each component by its regressor's range (a
    consequent multiplying W_r ~ 100 rad/s would otherwise adapt 10^4 times faster than
    a constant term and make the discrete update unstable); any positive diagonal Gamma
    keeps the Lyapunov argument (V uses theta~^T Gamma^-1 theta~ / 2 eta_f).
    A component outside its box whose update points further out is left alone.
    """
    if eta_f == 0.0 or e_eps == 0.0:
        return
    for i in range(theta_f.shape[0]):
        step = -eta_f * eta_scale[i] * phi_f[i] * e_eps * period_s
        if (theta_f[i] >= theta_max[i] and step > 0.0) or (
            theta_f[i] <= theta_min[i] and step < 0.0
        ):
            continue
        theta_f[i] += step


@njit(cache=True)
def adapt_theta_g(
    theta_g: float, u_eq: float, e_eps: float, gains: ChannelGains, period_s: float
) -> float:
    """theta_g += T (-eta_g e_eps u_eq), kept in [g0, g_max] so 1/g^ stays bounded."""
    updated = theta_g - gains.eta_g * e_eps * u_eq * period_s
    return min(gains.g_max, max(gains.g0, updated))


@njit(cache=True)
def lyapunov(e_eps: float, theta_f_err: np.ndarray, theta_g_err: float,
             eta_f: float, eta_scale: np.ndarray, eta_g: float) -> float:
    """V = 1/2 e_eps^2 + theta~_f^T Gamma^-1 theta~_f / (2 eta_f) + theta~_g^2 / (2 eta_g)
    (the paper's Eq. lyap with the diagonal Gamma of adapt_theta_f)."""
    v = 0.5 * e_eps * e_eps
    if eta_f > 0.0:
        v += 0.5 * np.sum(theta_f_err * theta_f_err / eta_scale) / eta_f
    if eta_g > 0.0:
        v += 0.5 * theta_g_err * theta_g_err / eta_g
    return v


# Indices into a channel's telemetry row (contracts.vectors.CHANNEL_INTERNALS), written by
# adaptive_channel_step.
TEL_REF, TEL_Y, TEL_E, TEL_ES, TEL_EEPS, TEL_FHAT, TEL_UEQ, TEL_US, TEL_V, TEL_THETA_G = range(
    len(CHANNEL_INTERNALS))


@njit(cache=True)
def adaptive_channel_step(
    y: float,
    y_dot: float,
    yd: float,
    yd_dot: float,
    yd_ddot: float,
    phi_f: np.ndarray,
    theta_f: np.ndarray,
    theta_min: np.ndarray,
    theta_max: np.ndarray,
    eta_scale: np.ndarray,
    f_offset: float,
    theta_g: float,
    gains: ChannelGains,
    period_s: float,
    telemetry: np.ndarray,
    angular: bool = False,
) -> tuple[float, float]:
    """One control period of one channel: returns (v, updated theta_g).

    f^ = theta_f . phi_f + f_offset (the offset carries a known, non-adapted model part).
    theta_f is updated in place, after the control is computed with the current values.
    ``angular``: y is an angle, so e = y_d - y is wrapped to [-pi, pi) and a heading
    across +-180 deg is reached the short way round.
    """
    e = wrap_pi(yd - y) if angular else yd - y
    e_dot = yd_dot - y_dot
    e_s = sliding_surface(e, e_dot, gains.lam)
    e_eps = boundary_layer_distance(e_s, gains.eps)
    f_hat = f_offset
    for i in range(theta_f.shape[0]):
        f_hat += theta_f[i] * phi_f[i]
    u_eq = equivalent_control(f_hat, theta_g, yd_ddot, e_eps, e_dot, gains)
    u_s = switching_control(u_eq, e_s, gains)
    v = u_eq + u_s
    telemetry[TEL_REF] = yd
    telemetry[TEL_Y] = y
    telemetry[TEL_E] = e
    telemetry[TEL_ES] = e_s
    telemetry[TEL_EEPS] = e_eps
    telemetry[TEL_FHAT] = f_hat
    telemetry[TEL_UEQ] = u_eq
    telemetry[TEL_US] = u_s
    telemetry[TEL_V] = v
    adapt_theta_f(theta_f, phi_f, e_eps, theta_min, theta_max, gains.eta_f, eta_scale,
                  period_s)
    theta_g = adapt_theta_g(theta_g, u_eq, e_eps, gains, period_s)
    telemetry[TEL_THETA_G] = theta_g
    return v, theta_g
