"""The sliding-mode cascade: altitude and position loops feeding the attitude loop, then
the mixer. One compiled function per control period (``cascade_step``) so a step costs
microseconds; the ``SlidingModeCascade`` class around it holds the state.

Flavours share this code: IVFC (interval type-2 basis), T1FC (type-1 basis) and SMC
(nominal model, no adaptation). Channel order everywhere: phi, theta, psi, z, x, y.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from autopilot.control.command_filter import command_filter_step
from autopilot.control.gains import channel_gains
from autopilot.control.mixer import mix
from autopilot.control.sliding_mode import adaptive_channel_step
from autopilot.models.regressors import CHANNEL_REGRESSORS
from autopilot.models.ts_model import it2_regressor, t1_regressor
from autopilot.parameters import validate_parameters
from contracts.airframe import (
    Airframe,
    attitude_drift,
    max_thrust_n,
    residual_rotor_speed,
    rotor_momentum,
    rotor_speeds,
)
from contracts.compiled import Resolved
from contracts.vectors import (
    ATTITUDE_CHANNELS,
    CHANNEL_INTERNALS,
    CHANNELS,
    MEAS_EULER,
    MEAS_EULER_RATE,
    MEAS_POS,
    MEAS_VEL,
    REF_ACC,
    REF_EULER,
    REF_EULER_ACC,
    REF_EULER_RATE,
    REF_POS,
    REF_VEL,
)

CH_Z, CH_X, CH_Y = (CHANNELS.index(name) for name in ("z", "x", "y"))
BASIS_IT2, BASIS_T1, BASIS_NOMINAL = 0, 1, 2


MIN_TILT_COSINE = 0.3  # altitude loop: c.phi c.theta is bounded away from 0
MIN_THRUST_FRACTION = 0.1  # position loop: U_z floor (fraction of weight) in u = -v / U_z


def _regressor_sources() -> np.ndarray:
    """Per attitude channel, where each regressor of CHANNEL_REGRESSORS (the one place
    that chooses them) comes from in flight: 0-2 the Euler rates, 3 W_r, -1 none."""
    source = {"phi_rate_rad_s": 0, "theta_rate_rad_s": 1, "psi_rate_rad_s": 2, "w_r_rad_s": 3}
    table = np.full((len(ATTITUDE_CHANNELS), 3), -1, dtype=np.int64)
    for ch, name in enumerate(ATTITUDE_CHANNELS):
        for j, regressor in enumerate(CHANNEL_REGRESSORS[name]):
            table[ch, j] = source[regressor]
    return table


REGRESSOR_SOURCES = _regressor_sources()


@njit(cache=True)
def attitude_regressor_inputs(meas: np.ndarray, w_r: float, channel: int) -> np.ndarray:
    """The channel's regressors now, e.g. f_phi(theta', psi', W_r) (CHANNEL_REGRESSORS)."""
    sources = REGRESSOR_SOURCES[channel]
    n = 0
    while n < sources.size and sources[n] >= 0:
        n += 1
    out = np.empty(n)
    for j in range(n):
        out[j] = w_r if sources[j] == 3 else meas[MEAS_EULER_RATE + sources[j]]
    return out


@njit(cache=True)
def desired_angles(u_x: float, u_y: float, psi_d: float, max_tilt: float,
                   total_tilt: bool = False) -> tuple[float, float]:
    """phi_d, theta_d that point the thrust along (u_x, u_y) (the paper's desired angles,
    signs corrected), within ``max_tilt`` (MPC_TILTMAX_AIR).

    (u_x, u_y) is the horizontal part of the unit thrust direction: |u| = sin(tilt) with
    cos(tilt) = c.phi c.theta. ``total_tilt`` limits the tilt itself, as PX4 does, by
    shortening u and keeping its direction (flights from tools); otherwise roll and pitch
    are clipped each (the paper's scenarios are tuned with that clip and keep it).
    """
    if total_tilt:
        reach = math.sqrt(u_x * u_x + u_y * u_y)
        largest = math.sin(max_tilt)
        if reach > largest:
            u_x *= largest / reach
            u_y *= largest / reach
    s, c = math.sin(psi_d), math.cos(psi_d)
    phi_d = math.asin(max(-1.0, min(1.0, u_x * s - u_y * c)))
    theta_d = math.asin(max(-1.0, min(1.0, (u_x * c + u_y * s) / math.cos(phi_d))))
    return max(-max_tilt, min(max_tilt, phi_d)), max(-max_tilt, min(max_tilt, theta_d))


@njit(cache=True)
def cascade_step(
    meas: np.ndarray,
    ref: np.ndarray,
    position_mode: bool,
    kick: np.ndarray,
    basis_kind: int,
    mf_lower: tuple,
    mf_upper: tuple,
    theta_f: tuple,
    theta_min: tuple,
    theta_max: tuple,
    eta_scale: tuple,
    theta_g: np.ndarray,
    gains: tuple,
    af: Airframe,
    filter_state: np.ndarray,
    filter_limits: np.ndarray,
    max_tilt: float,
    last_commands: np.ndarray,
    period_s: float,
    telemetry: np.ndarray,
    collective_thrust_n: float,
    total_tilt: bool,
) -> np.ndarray:
    """One control period: altitude, position (if active), attitude, mixer -> c_i.

    ``last_commands``: the motor commands sent last period (their rotor speeds give W_r and
    the rotors' momentum: the controller knows what it sent).

    ``collective_thrust_n``: NaN to run the altitude loop, else the total thrust a tool
    asked for (attitude setpoints in PX4's reading). ``total_tilt``: see desired_angles.
    """
    one = np.ones(1)
    phi, theta = meas[MEAS_EULER], meas[MEAS_EULER + 1]
    max_thrust = max_thrust_n(af)
    if math.isnan(collective_thrust_n):
        # Altitude: z'' = f_z + g_z v with v = -c.phi c.theta U_z.
        v_z, theta_g[CH_Z] = adaptive_channel_step(
            meas[MEAS_POS + 2], meas[MEAS_VEL + 2], ref[REF_POS + 2], ref[REF_VEL + 2],
            ref[REF_ACC + 2], one, theta_f[CH_Z], theta_min[CH_Z], theta_max[CH_Z], one, 0.0,
            theta_g[CH_Z], gains[CH_Z], period_s, telemetry[CH_Z],
        )
        tilt = max(math.cos(phi) * math.cos(theta), MIN_TILT_COSINE)
        u_z = min(max(-v_z / tilt, 0.0), max_thrust)
    else:
        telemetry[CH_Z, :] = np.nan
        u_z = min(max(collective_thrust_n, 0.0), max_thrust)

    yd = np.empty(3)
    yd_dot = np.empty(3)
    yd_ddot = np.empty(3)
    for k in range(3):
        yd[k] = ref[REF_EULER + k]
        yd_dot[k] = ref[REF_EULER_RATE + k]
        yd_ddot[k] = ref[REF_EULER_ACC + k]
    if position_mode:
        # Position: x'' = g_x v_x with v_x = -U_z u_x (likewise y), f = theta_f (0 by default).
        u_xy = np.empty(2)
        thrust_floor = max(u_z, MIN_THRUST_FRACTION * af.mass_kg * af.gravity_mps2)
        for k, ch in ((0, CH_X), (1, CH_Y)):
            v, theta_g[ch] = adaptive_channel_step(
                meas[MEAS_POS + k], meas[MEAS_VEL + k], ref[REF_POS + k], ref[REF_VEL + k],
                ref[REF_ACC + k], one, theta_f[ch], theta_min[ch], theta_max[ch], one, 0.0,
                theta_g[ch], gains[ch], period_s, telemetry[ch],
            )
            u_xy[k] = -v / thrust_floor
        phi_c, theta_c = desired_angles(u_xy[0], u_xy[1], ref[REF_EULER + 2], max_tilt,
                                        total_tilt)
        # Kicks on the desired angles enter before the command filter, as any change of
        # the desired angle does.
        phi_c += kick[0]
        theta_c += kick[1]
        omega, zeta, rate_max, acc_max = filter_limits
        yd[0], yd_dot[0], yd_ddot[0] = command_filter_step(
            filter_state[0], phi_c, period_s, omega, zeta, rate_max, acc_max)
        yd[1], yd_dot[1], yd_ddot[1] = command_filter_step(
            filter_state[1], theta_c, period_s, omega, zeta, rate_max, acc_max)
    else:
        yd[0] += kick[0]
        yd[1] += kick[1]
        for ch in (CH_X, CH_Y):
            telemetry[ch, :] = np.nan
        # Keep the filter on the current reference so switching modes is bumpless.
        for k in range(2):
            filter_state[k, 0] = yd[k]
            filter_state[k, 1] = yd_dot[k]

    # Attitude: y'' = f(x) + g U.
    rates = meas[MEAS_EULER_RATE:MEAS_EULER_RATE + 3]
    rotor_rad_s = rotor_speeds(last_commands, af)
    w_r = residual_rotor_speed(rotor_rad_s, af)
    f_nominal = attitude_drift(rates[0], rates[1], rates[2], rotor_momentum(rotor_rad_s, af),
                               af)
    u_att = np.empty(3)
    for ch in range(3):
        if basis_kind == BASIS_IT2:
            phi_f = it2_regressor(attitude_regressor_inputs(meas, w_r, ch), mf_lower[ch],
                                  mf_upper[ch])
            offset = 0.0
        elif basis_kind == BASIS_T1:
            phi_f = t1_regressor(attitude_regressor_inputs(meas, w_r, ch), mf_lower[ch])
            offset = 0.0
        else:
            phi_f = np.empty(0)
            offset = f_nominal[ch]
        u_att[ch], theta_g[ch] = adaptive_channel_step(
            meas[MEAS_EULER + ch], rates[ch], yd[ch], yd_dot[ch], yd_ddot[ch], phi_f,
            theta_f[ch], theta_min[ch], theta_max[ch], eta_scale[ch], offset, theta_g[ch],
            gains[ch], period_s, telemetry[ch], True,
        )
    return mix(u_z, u_att[0], u_att[1], u_att[2], af)


@dataclass
class AttitudeModel:
    """What the attitude loop starts from: per channel MFs, consequents and g."""

    basis_kind: int
    mf_lower: tuple[np.ndarray, np.ndarray, np.ndarray]
    mf_upper: tuple[np.ndarray, np.ndarray, np.ndarray]
    theta_f: tuple[np.ndarray, np.ndarray, np.ndarray]
    g: tuple[float, float, float]
    eta_scale: tuple[np.ndarray, np.ndarray, np.ndarray]


def regressor_scales(input_ranges: np.ndarray, n_rules: int, halves: int) -> np.ndarray:
    """Per-component adaptation scale for phi_f = [xi (x) [x; 1]] (halves = 2 for IT2):
    1 / max(1, |x_j|max)^2 for a term in x_j, 1 for the constant term."""
    reach = np.maximum(1.0, np.max(np.abs(np.asarray(input_ranges, dtype=float)), axis=1))
    per_rule = np.concatenate([1.0 / reach**2, [1.0]])
    return np.tile(per_rule, n_rules * halves)


def nominal_attitude_model(af: Airframe) -> AttitudeModel:
    """SMC baseline: the paper's model with the nominal airframe, nothing to adapt."""
    empty = np.zeros((0, 0, 3))
    b1, b2, b3 = (float(b) for b in af.input_gains)
    return AttitudeModel(
        BASIS_NOMINAL, (empty,) * 3, (empty,) * 3, (np.zeros(0),) * 3, (b1, b2, b3),
        (np.zeros(0),) * 3,
    )


class SlidingModeCascade:
    """IVFC / T1FC / SMC: the adaptive sliding-mode cascade with its state."""

    def __init__(
        self,
        model: AttitudeModel,
        airframe: Airframe,
        period_s: float = 0.01,
        parameters: dict[str, float] | None = None,
        adaptive: bool = True,
        initial_euler_rad: tuple[float, float] = (0.0, 0.0),
    ) -> None:
        self.model = model
        self.airframe = airframe
        self.period_s = period_s
        self.adaptive = adaptive
        self.parameters = validate_parameters(parameters or {})
        self.telemetry = np.zeros((len(CHANNELS), len(CHANNEL_INTERNALS)))
        self._theta_f = tuple(np.array(t, dtype=float) for t in model.theta_f) + (
            np.array([airframe.gravity_mps2]), np.zeros(1), np.zeros(1))
        self._theta_f_initial = tuple(t.copy() for t in self._theta_f)
        self.theta_g = np.array([*model.g, 1.0 / airframe.mass_kg, 1.0 / airframe.mass_kg,
                                 1.0 / airframe.mass_kg])
        self._theta_g_initial = self.theta_g.copy()
        self._initial_euler_rad = initial_euler_rad
        self._filter_state = np.zeros((2, 2))
        self._filter_state[:, 0] = initial_euler_rad
        self.apply_parameters(self.parameters)
        self._last_commands = np.zeros(4)
        self._cascade_step = Resolved(cascade_step)  # typed once, not each step

    def reset(self) -> None:
        """The adaptive weights, command filter and last command as made (a new flight)."""
        self.telemetry[...] = 0.0
        self._theta_f = tuple(t.copy() for t in self._theta_f_initial)
        self.theta_g = self._theta_g_initial.copy()
        self._filter_state = np.zeros((2, 2))
        self._filter_state[:, 0] = self._initial_euler_rad
        self._last_commands = np.zeros(4)

    def apply_parameters(self, parameters: dict[str, float]) -> None:
        """Take new gains (validated), e.g. from a ground station, without a restart."""
        self.parameters = validate_parameters(parameters)
        p = self.parameters
        groups = ("ATT", "ATT", "YAW", "ALT", "POS", "POS")
        self._gains = tuple(
            channel_gains(p, group, float(g), self.adaptive)
            for group, g in zip(groups, self._theta_g_initial, strict=True)
        )
        self._theta_min = tuple(t - p[f"{g}_BOX"] for t, g in zip(self._theta_f_initial, groups,
                                                                  strict=True))
        self._theta_max = tuple(t + p[f"{g}_BOX"] for t, g in zip(self._theta_f_initial, groups,
                                                                  strict=True))
        self._filter_limits = np.array(
            [p["CMDF_OMEGA"], p["CMDF_ZETA"], p["CMDF_RATE_MAX"], p["CMDF_ACC_MAX"]])
        self._max_tilt = math.radians(p["MPC_TILTMAX_AIR"])

    @property
    def theta_f(self) -> tuple[np.ndarray, ...]:
        return self._theta_f

    def residual_rotor_speed(self) -> float:
        """W_r = sum s_i W_i of the last command (the controller knows what it sent)."""
        return float(residual_rotor_speed(rotor_speeds(self._last_commands, self.airframe),
                                          self.airframe))

    def step(self, meas: np.ndarray, ref: np.ndarray, position_mode: bool,
             kick: np.ndarray | None = None, collective_thrust_n: float = math.nan,
             total_tilt: bool = False) -> np.ndarray:
        """Motor commands c_i in [0, 1] for this control period."""
        commands = self._cascade_step(
            meas, ref, position_mode, np.zeros(2) if kick is None else kick,
            self.model.basis_kind, self.model.mf_lower, self.model.mf_upper, self._theta_f,
            self._theta_min, self._theta_max, self.model.eta_scale, self.theta_g, self._gains,
            self.airframe, self._filter_state, self._filter_limits, self._max_tilt,
            self._last_commands, self.period_s, self.telemetry, collective_thrust_n,
            total_tilt,
        )
        self._last_commands = commands
        return commands
