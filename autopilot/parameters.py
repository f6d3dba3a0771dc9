"""The autopilot's named parameters: one table, used by the code, the CLI and the MAVLink
parameter protocol. Names fit MAVLink's 16-character param_id. ``integer`` marks the ones
PX4 declares INT32 (enum, boolean and int32 in its parameter definitions); they take
whole numbers only, and travel as INT32 in the PX4 flavour's parameter protocol. The
ArduPilot flavour shows these values under Copter's names and units
(autopilot/copter_parameters.py).

Controller gains first, then the vehicle's own (take-off, landing, failsafes) under
PX4's names where PX4 has one.

Sliding-mode groups: ATT (roll and pitch), YAW, ALT (altitude), POS (x and y). Each has
LAM (surface slope lambda, 1/s), GAM (reaching gain gamma, 1/s), EPS (boundary layer),
ETA_F and ETA_G (adaptation rates), WF and WG (switching gains W_f, W_g), G0 (lower bound
of g as a fraction of its initial value) and BOX (projection half-width of theta_f).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from contracts.airframe_file import AirframeSpec


@dataclass(frozen=True)
class ParamSpec:
    name: str
    default: float
    minimum: float
    maximum: float
    unit: str
    description: str
    choices: tuple[float, ...] = ()  # allowed values of an enumeration, () = any in range
    integer: bool = False  # whole numbers only: PX4's type is INT32 (else REAL32)


_SMC_GAINS = {
    # gain: (ATT, YAW, ALT, POS defaults), (min, max), unit, description
    "LAM": ((8.0, 4.0, 2.0, 5.0), (0.01, 100.0), "1/s", "sliding surface slope lambda"),
    "GAM": ((10.0, 10.0, 10.0, 2.0), (0.0, 200.0), "1/s", "reaching gain gamma"),
    "EPS": ((0.02, 0.02, 0.05, 0.3), (1e-4, 10.0), "", "boundary layer width epsilon"),
    "ETA_F": ((0.5, 0.5, 0.5, 0.0), (0.0, 1e3), "", "adaptation rate of theta_f"),
    "ETA_G": ((0.05, 0.05, 0.0005, 0.0005), (0.0, 1e3), "", "adaptation rate of theta_g"),
    "WF": ((0.1, 0.1, 0.1, 0.1), (0.0, 100.0), "", "switching gain W_f"),
    "WG": ((0.1, 0.1, 0.1, 0.1), (0.0, 100.0), "", "switching gain W_g"),
    "G0": ((0.5, 0.5, 0.5, 0.5), (0.01, 1.0), "", "g lower bound / initial g"),
    "BOX": ((50.0, 50.0, 50.0, 50.0), (0.0, 1e6), "", "theta_f projection half-width"),
}
SMC_GROUPS = ("ATT", "YAW", "ALT", "POS")


def _smc_specs() -> list[ParamSpec]:
    specs = []
    for group_index, group in enumerate(SMC_GROUPS):
        for gain, (defaults, (low, high), unit, text) in _SMC_GAINS.items():
            specs.append(
                ParamSpec(f"{group}_{gain}", defaults[group_index], low, high, unit,
                          f"{group} {text}")
            )
    return specs


PARAMETERS: tuple[ParamSpec, ...] = (
    *_smc_specs(),
    # 0.35 rad, the limit the paper scenarios are tuned with, exactly.
    ParamSpec("MPC_TILTMAX_AIR", math.degrees(0.35), 3.0, 80.0, "deg",
              "largest tilt the position loop asks for"),
    ParamSpec("CMDF_OMEGA", 10.0, 1.0, 200.0, "rad/s", "command filter natural frequency"),
    ParamSpec("CMDF_ZETA", 1.0, 0.3, 2.0, "", "command filter damping ratio"),
    ParamSpec("CMDF_RATE_MAX", 2.0, 0.1, 20.0, "rad/s", "command filter angle rate limit"),
    ParamSpec("CMDF_ACC_MAX", 8.0, 0.5, 500.0, "rad/s^2", "command filter angle acc. limit"),
    # PID baseline, PX4 multicopter defaults in physical units.
    ParamSpec("PID_ATT_P", 6.5, 0.0, 50.0, "1/s", "attitude P (rate setpoint per rad)"),
    ParamSpec("PID_RATE_P", 20.0, 0.0, 500.0, "1/s", "rate P (rad/s^2 per rad/s)"),
    ParamSpec("PID_RATE_I", 10.0, 0.0, 500.0, "1/s^2", "rate I"),
    ParamSpec("PID_RATE_D", 0.3, 0.0, 10.0, "", "rate D (on measurement)"),
    ParamSpec("PID_YAW_P", 2.8, 0.0, 50.0, "1/s", "yaw P"),
    ParamSpec("PID_YAWRATE_P", 8.0, 0.0, 500.0, "1/s", "yaw rate P"),
    ParamSpec("PID_XY_P", 0.95, 0.0, 20.0, "1/s", "position P (velocity per m)"),
    ParamSpec("PID_XY_VEL_P", 1.8, 0.0, 50.0, "1/s", "horizontal velocity P"),
    ParamSpec("PID_XY_VEL_I", 0.4, 0.0, 50.0, "1/s^2", "horizontal velocity I"),
    ParamSpec("PID_XY_VEL_D", 0.2, 0.0, 10.0, "", "horizontal velocity D"),
    ParamSpec("PID_Z_P", 1.0, 0.0, 20.0, "1/s", "altitude P"),
    ParamSpec("PID_Z_VEL_P", 4.0, 0.0, 50.0, "1/s", "vertical velocity P"),
    ParamSpec("PID_Z_VEL_I", 2.0, 0.0, 50.0, "1/s^2", "vertical velocity I"),
    # The vehicle (docs/mavlink.md): take-off, landing and failsafes.
    ParamSpec("MIS_TAKEOFF_ALT", 2.5, 0.5, 100.0, "m", "take-off altitude when none is given"),
    ParamSpec("MPC_TKO_SPEED", 1.0, 0.1, 5.0, "m/s", "climb speed of take-off"),
    ParamSpec("MPC_LAND_SPEED", 0.7, 0.1, 3.0, "m/s", "descent speed of landing"),
    ParamSpec("COM_DISARM_LAND", 1.0, 0.0, 20.0, "s", "disarm this long after touchdown"),
    ParamSpec("COM_DL_LOSS_T", 10.0, 1.0, 300.0, "s", "ground-station heartbeat loss timeout",
              integer=True),
    ParamSpec("NAV_DLL_ACT", 1.0, 0.0, 3.0, "", "on GCS loss: 0 none, 1 hold, 2 return, "
              "3 land", choices=(0.0, 1.0, 2.0, 3.0), integer=True),
    ParamSpec("COM_OF_LOSS_T", 1.0, 0.1, 60.0, "s", "offboard setpoint loss timeout"),
    ParamSpec("COM_OBL_ACT", 1.0, 0.0, 1.0, "", "on setpoint loss: 0 land, 1 hold",
              choices=(0.0, 1.0), integer=True),
    # Setpoint shaping (autopilot/flight_tasks/shaping.py): PX4's names, meanings and
    # units; defaults for the paper airframe (PX4's own defaults are for a 450-class quadrotor).
    ParamSpec("MPC_XY_VEL_MAX", 5.0, 0.5, 20.0, "m/s", "largest horizontal speed"),
    ParamSpec("MPC_Z_VEL_MAX_UP", 3.0, 0.5, 8.0, "m/s", "largest climb rate"),
    ParamSpec("MPC_Z_VEL_MAX_DN", 1.5, 0.5, 4.0, "m/s", "largest descent rate"),
    ParamSpec("MPC_ACC_HOR", 3.0, 0.5, 15.0, "m/s^2", "largest horizontal acceleration"),
    ParamSpec("MPC_ACC_UP_MAX", 4.0, 1.0, 15.0, "m/s^2", "largest upward acceleration"),
    ParamSpec("MPC_ACC_DOWN_MAX", 3.0, 1.0, 15.0, "m/s^2", "largest downward acceleration"),
    ParamSpec("MPC_JERK_AUTO", 4.0, 1.0, 80.0, "m/s^3", "largest jerk of the reference"),
    ParamSpec("MPC_YAWRAUTO_MAX", 45.0, 5.0, 360.0, "deg/s", "largest yaw rate"),
    ParamSpec("MPC_YAWRAUTO_ACC", 60.0, 5.0, 1000.0, "deg/s^2", "largest yaw acceleration"),
    ParamSpec("COM_SIM_LOSS_T", 0.5, 0.05, 60.0, "s", "simulator link loss timeout (-> land)"),
    ParamSpec("SYS_FAILURE_EN", 0.0, 0.0, 1.0, "", "failure injection from ground tools "
              "(MAV_CMD_INJECT_FAILURE): 0 off, 1 on", choices=(0.0, 1.0), integer=True),
    # The geofence (docs/missions.md): PX4's names; a limit of 0 is off.
    ParamSpec("GF_ACTION", 2.0, 0.0, 5.0, "", "on a fence breach: 0 none, 1 warn, 2 hold, "
              "3 return, 5 land", choices=(0.0, 1.0, 2.0, 3.0, 5.0), integer=True),
    ParamSpec("GF_MAX_HOR_DIST", 0.0, 0.0, 10000.0, "m", "largest distance from home (0 off)"),
    ParamSpec("GF_MAX_VER_DIST", 0.0, 0.0, 10000.0, "m", "largest height above home (0 off)"),
    # Missions and return (docs/missions.md): PX4's names; RTL altitudes lower than PX4's
    # 60 / 30 m, for a small vehicle flown close by.
    ParamSpec("MPC_XY_CRUISE", 5.0, 0.5, 20.0, "m/s", "mission speed (DO_CHANGE_SPEED sets it)"),
    ParamSpec("NAV_ACC_RAD", 2.0, 0.05, 200.0, "m", "waypoint acceptance radius"),
    ParamSpec("NAV_MC_ALT_RAD", 0.8, 0.05, 200.0, "m", "waypoint altitude acceptance"),
    ParamSpec("RTL_RETURN_ALT", 10.0, 0.5, 500.0, "m", "return altitude above home"),
    ParamSpec("RTL_DESCEND_ALT", 5.0, 0.5, 500.0, "m", "altitude return descends to first"),
    # Follow Me (AUTO.FOLLOW_TARGET, docs/missions.md): PX4's names and defaults.
    ParamSpec("FLW_TGT_HT", 8.0, 1.0, 500.0, "m", "follow height (above home; above the "
              "target with FLW_TGT_ALT_M 2)"),
    ParamSpec("FLW_TGT_DST", 8.0, 1.0, 500.0, "m", "horizontal distance to the target"),
    ParamSpec("FLW_TGT_FA", 180.0, -180.0, 180.0, "deg", "follow angle from the target's "
              "course, clockwise: 0 in front, 90 right, 180 behind"),
    ParamSpec("FLW_TGT_ALT_M", 0.0, 0.0, 2.0, "", "altitude: 0 constant, 1 terrain "
              "(flat here: constant), 2 track the target's", choices=(0.0, 1.0, 2.0),
              integer=True),
    ParamSpec("FLW_TGT_RS", 0.1, 0.0, 1.0, "", "smoothing of the target's position: 0 "
              "follows each report, 1 never moves"),
    ParamSpec("FLW_TGT_MAX_VEL", 5.0, 0.1, 20.0, "m/s", "largest speed round the target "
              "when the follow direction changes"),
    # Manual flight from MANUAL_CONTROL (docs/mavlink.md): PX4's stick meanings.
    ParamSpec("MPC_VEL_MANUAL", 5.0, 0.5, 20.0, "m/s", "full-stick speed in POSCTL"),
    ParamSpec("MPC_HOLD_DZ", 0.1, 0.0, 0.5, "", "stick deadband"),
    ParamSpec("MPC_XY_MAN_EXPO", 0.6, 0.0, 1.0, "", "horizontal stick expo (POSCTL)"),
    ParamSpec("MPC_Z_MAN_EXPO", 0.6, 0.0, 1.0, "", "throttle stick expo (climb rate)"),
    ParamSpec("MPC_MAN_TILT_MAX", 35.0, 1.0, 60.0, "deg", "full-stick tilt (ALTCTL, STAB.)"),
    ParamSpec("MPC_MAN_Y_MAX", 90.0, 5.0, 400.0, "deg/s", "full-stick yaw rate"),
    ParamSpec("COM_RC_LOSS_T", 0.5, 0.1, 35.0, "s", "manual control loss timeout"),
    ParamSpec("NAV_RCL_ACT", 2.0, 1.0, 3.0, "", "on manual control loss: 1 hold, 2 return, "
              "3 land", choices=(1.0, 2.0, 3.0), integer=True),
    # The estimator (--state-source estimator), PX4's EKF2 name.
    ParamSpec("EKF2_GPS_DELAY", 110.0, 0.0, 300.0, "ms", "GPS fix age on arrival"),
    ParamSpec("EKF2_NOAID_TOUT", 5e6, 5e5, 1e8, "us", "dead reckoning this long without a "
              "GPS fix fused: position lost (failsafe: land)", integer=True),
    # ArduPilot Copter: RC (docs/mavlink.md, RC as a ground tool sends it): Copter's names,
    # units (PWM us, s) and SITL's defaults (Tools/autotest/default_params/copter.parm).
    ParamSpec("SYSID_MYGCS", 255.0, 1.0, 255.0, "", "the ground station's system id: "
              "RC_CHANNELS_OVERRIDE and MANUAL_CONTROL only from it (ArduPilot flavour)"),
    *(ParamSpec(f"FLTMODE{i}", float(mode), 0.0, 27.0, "", f"Copter mode number of the "
                f"mode switch's position {i}") for i, mode in
      enumerate((7, 9, 6, 3, 5, 0), start=1)),
    ParamSpec("FLTMODE_CH", 5.0, 0.0, 16.0, "", "RC channel of the mode switch (0 none)"),
    ParamSpec("RC_OVERRIDE_TIME", 3.0, -1.0, 120.0, "s", "an RC override lasts this long "
              "after the last one for its channel (negative: forever)"),
    ParamSpec("FS_THR_ENABLE", 1.0, 0.0, 7.0, "", "radio failsafe: 0 off, 1 RTL, 2 RTL "
              "(AUTO continues), 3 LAND, 4-6 RTL, 7 LAND",
              choices=(0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0)),
    ParamSpec("FS_THR_VALUE", 975.0, 910.0, 1100.0, "us", "throttle PWM below which the "
              "radio has failed (three frames in a row)"),
    ParamSpec("THR_DZ", 100.0, 0.0, 300.0, "", "throttle deadzone around mid stick in "
              "ALT_HOLD / LOITER / POSHOLD, in throttle units (0-1000)"),
)
PARAMETER_SPECS: dict[str, ParamSpec] = {spec.name: spec for spec in PARAMETERS}
assert all(len(name) <= 16 for name in PARAMETER_SPECS)


def parse_assignment(text: str) -> tuple[str, float]:
    """``NAME=VALUE`` from a command line (both ``ivfm run`` and ``ivfm autopilot``)."""
    name, sep, value = text.partition("=")
    if not sep:
        raise ValueError(f"expected NAME=VALUE, got {text!r}")
    try:
        number = float(value)
    except ValueError:
        raise ValueError(f"{name}: {value!r} is not a number") from None
    if not math.isfinite(number):
        raise ValueError(f"{name}: {value!r} is not finite")
    return name.strip(), number


def default_parameters() -> dict[str, float]:
    return {spec.name: spec.default for spec in PARAMETERS}


def airframe_parameters(spec: AirframeSpec | None) -> dict[str, float]:
    """An airframe file's own parameter defaults ([parameters]), checked against the
    table; {} for none. The spec is read by the caller (once, at its edge)."""
    if spec is None:
        return {}
    own = dict(spec.parameters)
    try:
        validate_parameters(own)
    except ValueError as exc:
        raise ValueError(f"{spec.source}: parameters: {exc}") from None
    return own


def validate_parameters(overrides: dict[str, float]) -> dict[str, float]:
    """Defaults updated with ``overrides``; unknown names, NaN or out-of-range values raise."""
    params = default_parameters()
    for name, value in overrides.items():
        spec = PARAMETER_SPECS.get(name)
        if spec is None:
            raise ValueError(f"unknown parameter {name!r}")
        try:
            number = float(value)
        except (TypeError, ValueError):
            raise ValueError(
                f"parameter {name} must be a number, got {value!r}"
            ) from None
        if not math.isfinite(number) or not spec.minimum <= number <= spec.maximum:
            raise ValueError(
                f"parameter {name} must be finite and in "
                f"[{spec.minimum}, {spec.maximum}], got {value!r}"
            )
        if spec.integer and not number.is_integer():
            raise ValueError(f"parameter {name} takes whole numbers, got {value!r}")
        if spec.choices and number not in spec.choices:
            raise ValueError(f"parameter {name} must be one of "
                             f"{', '.join(f'{c:g}' for c in spec.choices)}, got {value!r}")
        params[name] = number
    return params
