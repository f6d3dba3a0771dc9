"""Baseline: a cascaded PID as PX4's multicopter controllers fly it.

Position P -> velocity PID -> acceleration -> thrust vector -> attitude P -> rate PID ->
torque (through the nominal inertia) -> the same mixer as the sliding-mode cascade.
Gains are PX4's defaults (MPC_*, MC_*) in physical units (see parameters.py).
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from autopilot.control.cascade import desired_angles
from autopilot.control.mixer import mix
from autopilot.parameters import validate_parameters
from contracts.airframe import Airframe, max_thrust_n
from contracts.frames import wrap_pi
from contracts.vectors import (
    MEAS_EULER,
    MEAS_EULER_RATE,
    MEAS_POS,
    MEAS_VEL,
    REF_ACC,
    REF_EULER,
    REF_EULER_RATE,
    REF_POS,
    REF_VEL,
)

# Integrator clamps (anti-windup), as PX4 bounds its integrators.
RATE_INTEGRATOR_LIMIT = 0.3  # rad (x RATE_I 10 -> 3 rad/s^2)
VELOCITY_INTEGRATOR_LIMIT = 2.0  # m (x VEL_I -> m/s^2)


class PidGains(NamedTuple):
    att_p: float
    rate_p: float
    rate_i: float
    rate_d: float
    yaw_p: float
    yawrate_p: float
    xy_p: float
    xy_vel_p: float
    xy_vel_i: float
    xy_vel_d: float
    z_p: float
    z_vel_p: float
    z_vel_i: float
    max_tilt: float


def pid_gains(p: dict[str, float]) -> PidGains:
    return PidGains(
        p["PID_ATT_P"], p["PID_RATE_P"], p["PID_RATE_I"], p["PID_RATE_D"], p["PID_YAW_P"],
        p["PID_YAWRATE_P"], p["PID_XY_P"], p["PID_XY_VEL_P"], p["PID_XY_VEL_I"],
        p["PID_XY_VEL_D"], p["PID_Z_P"], p["PID_Z_VEL_P"], p["PID_Z_VEL_I"],
        math.radians(p["MPC_TILTMAX_AIR"]),
    )


@njit(cache=True)
def _clip(value: float, limit: float) -> float:
    return max(-limit, min(limit, value))


@njit(cache=True)
def pid_step(
    meas: np.ndarray,
    ref: np.ndarray,
    position_mode: bool,
    kick: np.ndarray,
    gains: PidGains,
    integrators: np.ndarray,  # rate x3, xy velocity x2, z velocity
    previous: np.ndarray,  # rates x3, xy velocity x2 (for D on measurement)
    af: Airframe,
    period_s: float,
    telemetry: np.ndarray,
    collective_thrust_n: float,
    total_tilt: bool,
) -> np.ndarray:
    """One period; ``collective_thrust_n`` NaN runs the altitude loop (else the thrust);
    ``total_tilt`` as in :func:`cascade.desired_angles`."""
    g = af.gravity_mps2
    m = af.mass_kg
    phi, theta = meas[MEAS_EULER], meas[MEAS_EULER + 1]
    # Vertical: position P -> velocity PI -> acceleration (NED, plus feedforward).
    vz_sp = gains.z_p * (ref[REF_POS + 2] - meas[MEAS_POS + 2]) + ref[REF_VEL + 2]
    vz_err = vz_sp - meas[MEAS_VEL + 2]
    integrators[5] = _clip(integrators[5] + vz_err * period_s, VELOCITY_INTEGRATOR_LIMIT)
    az = gains.z_vel_p * vz_err + gains.z_vel_i * integrators[5] + ref[REF_ACC + 2]
    att_d = np.empty(3)
    rate_ff = np.empty(3)
    for k in range(3):
        att_d[k] = ref[REF_EULER + k]
        rate_ff[k] = ref[REF_EULER_RATE + k]
    if position_mode:
        acc = np.empty(2)
        for k in range(2):
            v_sp = gains.xy_p * (ref[REF_POS + k] - meas[MEAS_POS + k]) + ref[REF_VEL + k]
            v_err = v_sp - meas[MEAS_VEL + k]
            integrators[3 + k] = _clip(integrators[3 + k] + v_err * period_s,
                                        VELOCITY_INTEGRATOR_LIMIT)
            vel_rate = (meas[MEAS_VEL + k] - previous[3 + k]) / period_s
            previous[3 + k] = meas[MEAS_VEL + k]
            acc[k] = (gains.xy_vel_p * v_err + gains.xy_vel_i * integrators[3 + k]
                      - gains.xy_vel_d * vel_rate + ref[REF_ACC + k])
        u_z = m * math.sqrt(acc[0] ** 2 + acc[1] ** 2 + (g - az) ** 2)
        att_d[0], att_d[1] = desired_angles(-m * acc[0] / u_z, -m * acc[1] / u_z, att_d[2],
                                            gains.max_tilt, total_tilt)
        rate_ff[0] = 0.0
        rate_ff[1] = 0.0
    else:
        u_z = m * (g - az) / max(math.cos(phi) * math.cos(theta), 0.3)
    if not math.isnan(collective_thrust_n):
        u_z = collective_thrust_n
    u_z = min(max(u_z, 0.0), max_thrust_n(af))
    att_d[0] += kick[0]
    att_d[1] += kick[1]
    # Attitude P -> rate PID -> angular acceleration -> torque.
    alpha = np.empty(3)
    for k in range(3):
        err = wrap_pi(att_d[k] - meas[MEAS_EULER + k])
        rate = meas[MEAS_EULER_RATE + k]
        p_gain = gains.yaw_p if k == 2 else gains.att_p
        rate_err = p_gain * err + rate_ff[k] - rate
        integrators[k] = _clip(integrators[k] + rate_err * period_s, RATE_INTEGRATOR_LIMIT)
        if k == 2:
            alpha[k] = gains.yawrate_p * rate_err + gains.rate_i * 0.1 * integrators[k]
        else:
            d_rate = (rate - previous[k]) / period_s
            alpha[k] = (gains.rate_p * rate_err + gains.rate_i * integrators[k]
                        - gains.rate_d * d_rate)
        previous[k] = rate
        telemetry[k, 0] = att_d[k]
        telemetry[k, 1] = meas[MEAS_EULER + k]
        telemetry[k, 2] = err
    telemetry[3, 0] = ref[REF_POS + 2]
    telemetry[3, 1] = meas[MEAS_POS + 2]
    telemetry[3, 2] = ref[REF_POS + 2] - meas[MEAS_POS + 2]
    # The channel inputs with b U = alpha (the mixer applies the full inertia).
    b = af.input_gains
    return mix(u_z, alpha[0] / b[0], alpha[1] / b[1], alpha[2] / b[2], af)


class PidCascade:
    """PX4-style cascaded PID with its integrator state."""

    theta_g = None  # no adaptive weights
    theta_f = None

    def __init__(self, airframe: Airframe, period_s: float = 0.01,
                 parameters: dict[str, float] | None = None) -> None:
        self.airframe = airframe
        self.period_s = period_s
        self.apply_parameters(parameters or {})
        self._integrators = np.zeros(6)
        self._previous = np.zeros(5)
        self.telemetry = np.full((6, 10), np.nan)

    def reset(self) -> None:
        """Integrators and derivative memory cleared (a new flight)."""
        self._integrators = np.zeros(6)
        self._previous = np.zeros(5)
        self.telemetry = np.full((6, 10), np.nan)

    def apply_parameters(self, parameters: dict[str, float]) -> None:
        self.parameters = validate_parameters(parameters)
        self._gains = pid_gains(self.parameters)

    def step(self, meas: np.ndarray, ref: np.ndarray, position_mode: bool,
             kick: np.ndarray | None = None, collective_thrust_n: float = math.nan,
             total_tilt: bool = False) -> np.ndarray:
        return pid_step(meas, ref, position_mode, np.zeros(2) if kick is None else kick,
                        self._gains, self._integrators, self._previous, self.airframe,
                        self.period_s, self.telemetry, collective_thrust_n, total_tilt)
