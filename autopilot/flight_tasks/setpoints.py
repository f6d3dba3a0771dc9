"""Flight tasks: what the vehicle flies to when the paper's reference does not drive it.

A held or streamed position / velocity setpoint goes through the setpoint shaper
(autopilot/flight_tasks/shaping.py) into a smooth reference; an attitude target goes through the
attitude shaper, with an altitude loop or a collective thrust. Take-off and landing are
setpoints with their own climb and descent limits (the vehicle sets those). Pure: the
measurement, limits and times come in as arguments.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from autopilot.flight_tasks.shaping import Setpoint, SetpointShaper, ShapingLimits
from autopilot.refusal import RefusedError, check_finite, check_given
from contracts.frames import euler_from_quat, wrap_pi
from contracts.vectors import MEAS_YAW, MEAS_Z, MEASUREMENT, REF_POS, REF_VEL

MAX_SETPOINT_DISTANCE_M = 1000.0
MAX_SETPOINT_SPEED_MPS = 20.0
MAX_SETPOINT_ACCEL_MPS2 = 20.0
MAX_SETPOINT_YAW_RATE_RAD_S = 20.0
MAX_TILT_SETPOINT_RAD = 1.0
# A position setpoint's velocity / acceleration feed-forward is the setpoint's own motion:
# it applies while the streamed position moves, and lapses this long after it stops, so
# a setpoint that stands still is a place to stop at, not to fly past.
FEED_FORWARD_HOLD_S = 0.5


@dataclass
class AttitudeTarget:
    """An attitude setpoint: Euler angles, and the vertical part as the flavour reads
    SET_ATTITUDE_TARGET's thrust."""

    euler_rad: np.ndarray
    thrust_fraction: float = math.nan  # PX4: collective thrust / the airframe's maximum
    climb_rate_mps: float = 0.0  # ArduPilot (or no thrust): altitude loop at this rate
    altitude_ref_ned_m: float = math.nan  # the altitude loop's reference, integrated
    yaw_rate_rad_s: float = math.nan  # with a NaN yaw: turn at this rate (manual sticks)


def checked_position_setpoint(setpoint: Setpoint) -> Setpoint:
    """A copy of a local NED setpoint (NaN for what the tool left out) after the checks:
    per axis group a position or a velocity; everything given within range."""
    sp = Setpoint(np.array(setpoint.position_ned_m, dtype=float),
                  np.array(setpoint.velocity_ned_mps, dtype=float),
                  np.array(setpoint.accel_ned_mps2, dtype=float),
                  float(setpoint.yaw_rad), float(setpoint.yaw_rate_rad_s))
    pos, vel = sp.position_ned_m, sp.velocity_ned_mps
    if np.isnan(pos[0]) != np.isnan(pos[1]):
        raise RefusedError("setpoint gives x without y or y without x")
    for group in (slice(0, 2), slice(2, 3)):
        if np.all(np.isnan(pos[group])) and np.any(np.isnan(vel[group])):
            raise RefusedError("setpoint gives neither position nor velocity")
    check_given("setpoint position", pos, MAX_SETPOINT_DISTANCE_M)
    check_given("setpoint velocity", vel, MAX_SETPOINT_SPEED_MPS)
    check_given("setpoint acceleration", sp.accel_ned_mps2, MAX_SETPOINT_ACCEL_MPS2)
    check_given("setpoint yaw", (sp.yaw_rad,), math.inf)
    check_given("setpoint yaw rate", (sp.yaw_rate_rad_s,), MAX_SETPOINT_YAW_RATE_RAD_S)
    sp.yaw_rad = wrap_pi(sp.yaw_rad)
    return sp


def checked_attitude_target(quaternion: tuple | None, thrust: float | None, flavour: str,
                            climb_speed_mps: float) -> AttitudeTarget:
    """An attitude setpoint after the checks. Thrust as the flavour reads it: PX4, the
    collective thrust as a fraction of the maximum; ArduPilot, 0.5 holds the altitude and
    0 / 1 descend / climb at ``climb_speed_mps``. Without thrust the altitude is held."""
    if quaternion is None:
        raise RefusedError("attitude setpoint without attitude: body-rate control is not "
                           "supported")
    check_finite("attitude quaternion", quaternion, 1.01)
    q = np.array(quaternion, dtype=float)
    norm = float(np.linalg.norm(q))
    if not 0.9 < norm < 1.1:
        raise RefusedError(f"attitude quaternion norm {norm:.3f} is not 1")
    euler = euler_from_quat(q / norm)
    if max(abs(euler[0]), abs(euler[1])) > MAX_TILT_SETPOINT_RAD:
        raise RefusedError(f"attitude setpoint tilts more than {MAX_TILT_SETPOINT_RAD} rad")
    target = AttitudeTarget(euler)
    if thrust is not None:
        check_finite("thrust", (thrust,), 1.0)
        if thrust < 0.0:
            raise RefusedError(f"thrust {thrust:g} is outside [0, 1]")
        if flavour == "px4":
            target.thrust_fraction = float(thrust)
        else:
            target.climb_rate_mps = (thrust - 0.5) * 2.0 * climb_speed_mps
    return target


class FlightTasks:
    """The setpoint the vehicle flies to, the newest one a tool streamed, and the shaper
    that turns them into the controller's reference."""

    def __init__(self) -> None:
        self.setpoint = Setpoint.hold((0.0, 0.0, 0.0), 0.0)
        self.attitude_target: AttitudeTarget | None = None  # bypasses the setpoint
        self.shaper = SetpointShaper()
        # Which shaper path produced the last reference: None, "translation", "attitude".
        self.shaped: str | None = None
        self.streamed: Setpoint | AttitudeTarget | None = None  # newest, before offboard
        self._tool_position: np.ndarray | None = None
        self._tool_position_moved_s = -math.inf

    def hold_here(self, measurement: np.ndarray | None, limits: ShapingLimits) -> None:
        """Hold where the vehicle can stop: the shaped reference's stopping point when it
        is moving one, else the measured position; the heading it has."""
        if self.shaped == "translation":
            yaw = self.shaper.yaw_rad
        else:
            yaw = 0.0 if measurement is None else wrap_pi(float(measurement[MEAS_YAW]))
        self.setpoint = Setpoint.hold(self.stopping_point(measurement, limits), yaw)
        self.attitude_target = None

    def stopping_point(self, measurement: np.ndarray | None, limits: ShapingLimits
                       ) -> np.ndarray:
        """Where the vehicle can come to rest: the shaped reference's stopping point while
        one is flown, else the measured position."""
        if self.shaped == "translation":
            return self.shaper.stopping_point(limits)
        if measurement is None:
            return np.zeros(3)
        return measurement[MEASUREMENT.position_ned_m].copy()

    def stream_position(self, link_t_s: float, setpoint: Setpoint) -> None:
        """Take a checked position setpoint as the newest streamed one. Its velocity and
        acceleration feed-forward lapse FEED_FORWARD_HOLD_S after its position stops."""
        pos, vel = setpoint.position_ned_m, setpoint.velocity_ned_mps
        given = np.isfinite(pos)
        if np.any(given):
            if self._tool_position is None or not np.array_equal(
                    given, np.isfinite(self._tool_position)) or np.any(
                    np.abs(pos[given] - self._tool_position[given]) > 1e-6):
                self._tool_position_moved_s = link_t_s
            self._tool_position = pos.copy()
            if link_t_s - self._tool_position_moved_s > FEED_FORWARD_HOLD_S:
                vel[given] = np.nan
                setpoint.accel_ned_mps2[given] = np.nan
        self.streamed = setpoint

    def apply_streamed(self, measurement: np.ndarray | None) -> None:
        """The newest streamed setpoint becomes what the vehicle flies to."""
        streamed = self.streamed
        if isinstance(streamed, Setpoint):
            self.setpoint = streamed
            self.attitude_target = None
        elif isinstance(streamed, AttitudeTarget):
            previous = self.attitude_target
            if previous is not None:
                streamed.altitude_ref_ned_m = previous.altitude_ref_ned_m
            elif measurement is not None:
                streamed.altitude_ref_ned_m = float(measurement[MEAS_Z])
            self.attitude_target = streamed

    def translation_reference(self, measurement: np.ndarray, limits: ShapingLimits,
                              period_s: float) -> np.ndarray:
        """The setpoint shaped into this period's reference (the shaper starts from the
        vehicle's own position and velocity when it takes over)."""
        self.start_translation(measurement)
        return self.shaper.step(self.setpoint, limits, period_s)

    def start_translation(self, measurement: np.ndarray) -> None:
        """Start translation shaping from the vehicle's state, unless it is on already."""
        if self.shaped != "translation":
            self.shaper.reset(measurement[MEASUREMENT.position_ned_m],
                              measurement[MEASUREMENT.velocity_ned_mps], measurement[MEAS_YAW])
            self.shaped = "translation"

    def attitude_reference(self, measurement: np.ndarray, limits: ShapingLimits,
                           filter_limits: tuple[float, float, float, float], period_s: float,
                           max_thrust_n: float) -> tuple[np.ndarray, bool, float]:
        """The attitude target's reference, the position loop off, and a collective thrust
        [N] replacing the altitude loop (NaN: the altitude loop runs)."""
        target = self.attitude_target
        if self.shaped != "attitude":
            self.shaper.reset_attitude(measurement[MEASUREMENT.euler_rad],
                                       measurement[MEASUREMENT.euler_rate_rad_s])
            self.shaped = "attitude"
        ref = self.shaper.step_attitude(target.euler_rad, limits, filter_limits, period_s,
                                        target.yaw_rate_rad_s)
        ref[REF_POS:REF_POS + 3] = measurement[MEASUREMENT.position_ned_m]
        if math.isfinite(target.thrust_fraction):
            return ref, False, target.thrust_fraction * max_thrust_n
        target.altitude_ref_ned_m -= target.climb_rate_mps * period_s
        ref[REF_POS + 2] = target.altitude_ref_ned_m
        ref[REF_VEL + 2] = -target.climb_rate_mps
        return ref, False, math.nan
