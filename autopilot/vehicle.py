"""The vehicle's logic: arming, modes, take-off, landing, setpoints and failsafes.

Pure (no sockets, no clocks): the process shell calls it with two times.
* ``sim_t_s`` (sim time) drives everything in the control path: ramps, the reference
  generator, landing detection, the controller.
* ``link_t_s`` (the link clock, wall time in the shell) times what ground tools do:
  heartbeats, setpoint streams and the simulator link, which arrive in wall time.
A lockstep scenario without a ground tool never reads the link clock, so it stays
deterministic. Every refusal returns a reason that the shell sends as STATUSTEXT.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from autopilot.control.parameters import validate_parameters
from autopilot.reference import Reference
from autopilot.shaping import Setpoint, SetpointShaper, ShapingLimits, limits_from_parameters
from contracts.airframe import max_thrust_n
from contracts.frames import euler_from_quat, wrap_pi
from contracts.modes import FlightMode
from contracts.perturbations import Perturbation, PerturbationBook, kick_at
from contracts.telemetry import AUTOPILOT
from contracts.vectors import MEAS_VZ, MEAS_YAW, MEAS_Z, MEASUREMENT, REF_POS, REF_SIZE, REF_VEL

LANDED_ALTITUDE_M = 0.05  # the plant's ground is z = 0
LANDED_SPEED_MPS = 0.1
TAKEOFF_REACHED_M = 0.1
LAND_REFERENCE_Z_M = 0.5  # landing descends towards 0.5 m below the ground: it touches down
MAX_SETPOINT_DISTANCE_M = 1000.0
MAX_SETPOINT_SPEED_MPS = 20.0
MAX_SETPOINT_ACCEL_MPS2 = 20.0
MAX_SETPOINT_YAW_RATE_RAD_S = 20.0
MAX_TILT_SETPOINT_RAD = 1.0
# A position setpoint's velocity / acceleration feed-forward is the setpoint's own motion:
# it applies while the streamed position moves, and lapses this long after it stops, so
# a setpoint that stands still is a place to stop at, not to fly past.
FEED_FORWARD_HOLD_S = 0.5
ARMABLE_MODES = (FlightMode.HOLD, FlightMode.GUIDED, FlightMode.OFFBOARD, FlightMode.TAKEOFF)


class RefusedError(Exception):
    """A request the vehicle will not carry out, with the reason for the ground tool."""

    def __init__(self, reason: str, temporary: bool = False) -> None:
        super().__init__(reason)
        self.temporary = temporary  # MAV_RESULT_TEMPORARILY_REJECTED rather than DENIED


@dataclass
class AttitudeTarget:
    """An attitude setpoint: Euler angles, and the vertical part as the flavour reads
    SET_ATTITUDE_TARGET's thrust."""

    euler_rad: np.ndarray
    thrust_fraction: float = math.nan  # PX4: collective thrust / the airframe's maximum
    climb_rate_mps: float = 0.0  # ArduPilot (or no thrust): altitude loop at this rate
    altitude_ref_ned_m: float = math.nan  # the altitude loop's reference, integrated


def _check(name: str, values, limit: float) -> None:
    for v in values:
        if not math.isfinite(v):
            raise RefusedError(f"{name} holds NaN or infinity")
        if abs(v) > limit:
            raise RefusedError(f"{name} {v:g} is beyond +-{limit:g}")


def _check_given(name: str, values: np.ndarray, limit: float) -> None:
    """NaN marks a left-out value here; what is given must be within +-limit."""
    for v in values:
        if math.isinf(v):
            raise RefusedError(f"{name} holds an infinity")
        if abs(v) > limit:
            raise RefusedError(f"{name} {v:g} is beyond +-{limit:g}")


class Vehicle:
    """Arming state, mode, setpoints, failsafes and the controller they feed."""

    def __init__(
        self,
        make_controller: Callable[[dict[str, float]], object],
        period_s: float,
        parameters: dict[str, float] | None = None,
        reference: Reference | None = None,
        schedule: tuple[Perturbation, ...] = (),
        flavour: str = "px4",
    ) -> None:
        self._make_controller = make_controller
        self.period_s = period_s
        self.parameters = validate_parameters(parameters or {})
        self.limits: ShapingLimits = limits_from_parameters(self.parameters)
        self.controller = make_controller(self.parameters)
        self.reference = reference
        # Reference kicks (sim time), from the command line and from Zenoh requests.
        self.perturbations = PerturbationBook(AUTOPILOT, schedule)
        self.flavour = flavour
        self.armed = False
        self.mode = FlightMode.GUIDED if flavour == "ardupilot" else FlightMode.HOLD
        # What the vehicle flies to in the shaped modes, and the shaper in front of the
        # controller (autopilot/shaping.py); an attitude setpoint bypasses both.
        self.setpoint = Setpoint.hold((0.0, 0.0, 0.0), 0.0)
        self.attitude_target: AttitudeTarget | None = None
        self.shaper = SetpointShaper()
        # Which shaper path produced the last reference: None, "translation", "attitude".
        self._shaped: str | None = None
        self._streamed: Setpoint | AttitudeTarget | None = None  # newest, before offboard
        self._tool_position: np.ndarray | None = None
        self._tool_position_moved_s = -math.inf
        self.measurement: np.ndarray | None = None
        self.sim_t_s = 0.0
        self.reference_start_s = 0.0
        self.landed = True
        self._landed_since_s: float | None = 0.0
        self.takeoff_altitude_m: float | None = None
        self.failsafe: str | None = None
        self.messages: list[tuple[int, str]] = []  # (MAV_SEVERITY, text) for STATUSTEXT
        # link clock
        self.gcs_heard_s: float | None = None
        self.gcs_lost = False
        self.setpoint_heard_s: float | None = None
        self.sim_link_ok = False
        self.last_ref = np.zeros(REF_SIZE)
        self.last_kick = np.zeros(2)
        self.last_commands = np.zeros(4)

    # -- announcements -----------------------------------------------------------------
    def say(self, text: str, severity: int = 6) -> None:
        """Queue a STATUSTEXT (severity: 3 error, 4 warning, 5 notice, 6 info)."""
        self.messages.append((severity, text[:50]))

    # -- parameters --------------------------------------------------------------------
    def set_parameter(self, name: str, value: float) -> None:
        """Change one parameter; it takes effect at the next control step."""
        try:
            updated = validate_parameters({**self.parameters, name: value})
        except ValueError as exc:
            raise RefusedError(str(exc)) from None
        self.parameters = updated
        self.limits = limits_from_parameters(updated)
        self.controller.apply_parameters(updated)

    # -- state from the simulator --------------------------------------------------------
    @property
    def altitude_m(self) -> float:
        return 0.0 if self.measurement is None else -float(self.measurement[MEAS_Z])

    @property
    def heading_rad(self) -> float:
        """The vehicle's yaw now (0 before any state arrived)."""
        return 0.0 if self.measurement is None else wrap_pi(float(self.measurement[MEAS_YAW]))

    def _hold_here(self) -> None:
        """Hold where the vehicle can stop: the shaped reference's stopping point when it
        is moving one, else the measured position; the heading it has."""
        m = self.measurement
        if self._shaped == "translation":
            position, yaw = self.shaper.stopping_point(self.limits), self.shaper.yaw_rad
        else:
            position = m[MEASUREMENT.position_ned_m].copy() if m is not None else np.zeros(3)
            yaw = self.heading_rad
        self.setpoint = Setpoint.hold(position, yaw)
        self.attitude_target = None

    # -- commands ------------------------------------------------------------------------
    def arm(self, link_t_s: float) -> None:
        if self.armed:
            return
        if not self.sim_link_ok or self.measurement is None:
            raise RefusedError("arming denied: no state from the simulator", temporary=True)
        if self.mode not in ARMABLE_MODES:
            raise RefusedError(f"arming denied in {self.mode.value} mode")
        if not self.landed:
            raise RefusedError("arming denied: not on the ground")
        if self.mode == FlightMode.OFFBOARD and not self.setpoints_streaming(link_t_s):
            raise RefusedError("arming denied: no offboard setpoints", temporary=True)
        self._arm()
        self.say("armed")

    def _arm(self) -> None:
        self.controller = self._make_controller(self.parameters)
        self.armed = True
        self.failsafe = None  # a new flight: what went wrong before is over
        self._shaped = None
        self.last_ref = np.zeros(REF_SIZE)
        if self.mode != FlightMode.OFFBOARD:
            self._hold_here()
        else:
            self._apply_streamed()
        self._landed_since_s = None if not self.landed else self.sim_t_s

    def arm_in_reference(self) -> None:
        """Scenario runs: fly the reference from the first sample, wherever the vehicle is."""
        if self.reference is None:
            raise RefusedError("no reference generator configured")
        self.controller = self._make_controller(self.parameters)
        self.armed = True
        self.mode = FlightMode.REFERENCE
        self.reference_start_s = self.sim_t_s
        self.landed = False

    def disarm(self, force: bool = False) -> None:
        if not self.armed:
            return
        if not self.landed and not force:
            raise RefusedError("disarming denied: in the air (force with param2 21196)")
        self._disarm("disarmed")

    def _disarm(self, text: str) -> None:
        self.armed = False
        self._shaped = None
        self.takeoff_altitude_m = None
        if self.mode in (FlightMode.LAND, FlightMode.TAKEOFF, FlightMode.REFERENCE):
            self.mode = FlightMode.GUIDED if self.flavour == "ardupilot" else FlightMode.HOLD
        self.say(text)

    def takeoff(self, relative_altitude_m: float | None) -> None:
        alt = self.parameters["MIS_TAKEOFF_ALT"] if relative_altitude_m is None \
            else relative_altitude_m
        if not math.isfinite(alt) or not 0.5 <= alt <= 100.0:
            raise RefusedError(f"take-off altitude {alt:g} m is outside [0.5, 100] m")
        if not self.armed:
            raise RefusedError("take-off denied: disarmed", temporary=True)
        if self.flavour == "ardupilot" and self.mode != FlightMode.GUIDED:
            raise RefusedError("take-off needs GUIDED mode")
        if self.flavour == "px4":
            self.mode = FlightMode.TAKEOFF
        self._hold_here()
        self.setpoint.position_ned_m[2] = -alt
        self.takeoff_altitude_m = alt
        self.say(f"taking off to {alt:.1f} m")

    def land(self) -> None:
        if not self.armed:
            raise RefusedError("landing denied: disarmed", temporary=True)
        self._enter(FlightMode.LAND)

    def set_mode(self, mode: FlightMode, link_t_s: float) -> None:
        if mode == self.mode:
            return
        if mode == FlightMode.OFFBOARD and not self.setpoints_streaming(link_t_s):
            raise RefusedError("offboard denied: no setpoint stream", temporary=True)
        if mode == FlightMode.REFERENCE:
            if self.reference is None:
                raise RefusedError("no reference generator configured")
            if not self.armed or self.landed:
                raise RefusedError("the reference needs an armed vehicle in the air",
                                   temporary=True)
        if mode == FlightMode.TAKEOFF:
            self.takeoff(None)
            return
        if mode == FlightMode.LAND and not self.armed:
            raise RefusedError("landing denied: disarmed", temporary=True)
        self._enter(mode)

    def _enter(self, mode: FlightMode) -> None:
        previous = self.mode
        self.mode = mode
        self.takeoff_altitude_m = None
        if mode in (FlightMode.HOLD, FlightMode.LAND) or (
                mode == FlightMode.GUIDED and previous != FlightMode.OFFBOARD):
            self._hold_here()
        if mode == FlightMode.LAND:
            self.setpoint.position_ned_m[2] = LAND_REFERENCE_Z_M
        if mode == FlightMode.OFFBOARD:
            self._apply_streamed()
        if mode == FlightMode.REFERENCE:
            self.reference_start_s = self.sim_t_s
        self.say(f"mode {mode.value}")

    # -- setpoints -----------------------------------------------------------------------
    def setpoints_streaming(self, link_t_s: float) -> bool:
        return (self.setpoint_heard_s is not None
                and link_t_s - self.setpoint_heard_s <= self.parameters["COM_OF_LOSS_T"])

    def position_setpoint(self, link_t_s: float, setpoint: Setpoint) -> None:
        """A local NED setpoint (NaN for what the tool left out); checked before anything
        changes. Per axis group a position (velocity and acceleration then feed-forward)
        or a velocity; a yaw or a yaw rate (docs/mavlink.md)."""
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
        _check_given("setpoint position", pos, MAX_SETPOINT_DISTANCE_M)
        _check_given("setpoint velocity", vel, MAX_SETPOINT_SPEED_MPS)
        _check_given("setpoint acceleration", sp.accel_ned_mps2, MAX_SETPOINT_ACCEL_MPS2)
        _check_given("setpoint yaw", (sp.yaw_rad,), math.inf)
        _check_given("setpoint yaw rate", (sp.yaw_rate_rad_s,), MAX_SETPOINT_YAW_RATE_RAD_S)
        sp.yaw_rad = wrap_pi(sp.yaw_rad)
        self.setpoint_heard_s = link_t_s
        given = np.isfinite(pos)
        if np.any(given):
            if self._tool_position is None or not np.array_equal(
                    given, np.isfinite(self._tool_position)) or np.any(
                    np.abs(pos[given] - self._tool_position[given]) > 1e-6):
                self._tool_position_moved_s = link_t_s
            self._tool_position = pos.copy()
            if link_t_s - self._tool_position_moved_s > FEED_FORWARD_HOLD_S:
                vel[given] = np.nan
                sp.accel_ned_mps2[given] = np.nan
        self._streamed = sp
        if self.mode in (FlightMode.OFFBOARD, FlightMode.GUIDED):
            self._apply_streamed()

    def attitude_setpoint(self, link_t_s: float, quaternion: tuple | None,
                          thrust: float | None) -> None:
        """An attitude setpoint. Thrust as the flavour reads it: PX4, the collective
        thrust as a fraction of the maximum; ArduPilot, 0.5 holds the altitude and 0 / 1
        descend / climb at MPC_TKO_SPEED. Without thrust the altitude is held."""
        if quaternion is None:
            raise RefusedError("attitude setpoint without attitude: body-rate control is not "
                               "supported")
        _check("attitude quaternion", quaternion, 1.01)
        q = np.array(quaternion, dtype=float)
        norm = float(np.linalg.norm(q))
        if not 0.9 < norm < 1.1:
            raise RefusedError(f"attitude quaternion norm {norm:.3f} is not 1")
        euler = euler_from_quat(q / norm)
        if max(abs(euler[0]), abs(euler[1])) > MAX_TILT_SETPOINT_RAD:
            raise RefusedError(f"attitude setpoint tilts more than {MAX_TILT_SETPOINT_RAD} rad")
        target = AttitudeTarget(euler)
        if thrust is not None:
            _check("thrust", (thrust,), 1.0)
            if thrust < 0.0:
                raise RefusedError(f"thrust {thrust:g} is outside [0, 1]")
            if self.flavour == "px4":
                target.thrust_fraction = float(thrust)
            else:
                target.climb_rate_mps = (thrust - 0.5) * 2.0 * self.parameters["MPC_TKO_SPEED"]
        self.setpoint_heard_s = link_t_s
        self._streamed = target
        if self.mode in (FlightMode.OFFBOARD, FlightMode.GUIDED):
            self._apply_streamed()

    def _apply_streamed(self) -> None:
        """The newest streamed setpoint becomes what the vehicle flies to."""
        streamed = self._streamed
        if isinstance(streamed, Setpoint):
            self.setpoint = streamed
            self.attitude_target = None
        elif isinstance(streamed, AttitudeTarget):
            previous = self.attitude_target
            if previous is not None:
                streamed.altitude_ref_ned_m = previous.altitude_ref_ned_m
            elif self.measurement is not None:
                streamed.altitude_ref_ned_m = float(self.measurement[MEAS_Z])
            self.attitude_target = streamed

    # -- links ---------------------------------------------------------------------------
    def gcs_heartbeat(self, link_t_s: float) -> None:
        self.gcs_heard_s = link_t_s
        if self.gcs_lost:
            self.gcs_lost = False
            self.say("ground station link regained", 5)

    def check_links(self, link_t_s: float) -> None:
        """Failsafes timed on the link clock: ground station and setpoint stream."""
        p = self.parameters
        if (self.gcs_heard_s is not None and not self.gcs_lost
                and link_t_s - self.gcs_heard_s > p["COM_DL_LOSS_T"]):
            self.gcs_lost = True
            action = int(p["NAV_DLL_ACT"])
            self._failsafe("ground station lost", {0: None, 1: FlightMode.HOLD,
                                                   3: FlightMode.LAND}[action])
        if self.mode == FlightMode.OFFBOARD and self.armed and not self.setpoints_streaming(
                link_t_s):
            action = FlightMode.LAND if p["COM_OBL_ACT"] == 0 else FlightMode.HOLD
            self._failsafe("offboard setpoints lost", action)
        elif self.mode == FlightMode.OFFBOARD and not self.armed and not \
                self.setpoints_streaming(link_t_s):
            self.mode = FlightMode.HOLD

    def sim_link_lost(self) -> None:
        if not self.sim_link_ok:
            return
        self.sim_link_ok = False
        self._failsafe("simulator link lost", FlightMode.LAND)

    def _failsafe(self, what: str, action: FlightMode | None) -> None:
        self.failsafe = what
        if not self.armed or action is None:
            self.say(f"{what}", 4)
            return
        if self.landed:
            self._disarm(f"{what}: disarmed on the ground")
            return
        self.say(f"{what}: {action.value}", 4)
        if self.mode != action:
            self._enter(action)

    # -- the control step ----------------------------------------------------------------
    def sample(self, sim_t_s: float, measurement: np.ndarray) -> None:
        """New state from the simulator. A clock going back means a new simulator."""
        if self.measurement is not None and sim_t_s < self.sim_t_s:
            self.say("simulator restarted", 5)
            if self.armed and -measurement[MEAS_Z] < LANDED_ALTITUDE_M:
                self._disarm("simulator restarted: disarmed on the ground")
        if not self.sim_link_ok:
            self.say("simulator link up", 6)
        self.sim_link_ok = True
        self.sim_t_s = sim_t_s
        self.measurement = measurement
        self._detect_landing()

    def _detect_landing(self) -> None:
        m = self.measurement
        on_ground = (-m[MEAS_Z] < LANDED_ALTITUDE_M and abs(m[MEAS_VZ]) < LANDED_SPEED_MPS
                     and not (self.armed and self.mode == FlightMode.TAKEOFF)
                     and not (self.armed and self.takeoff_altitude_m is not None))
        if on_ground and self.armed and self.mode not in (FlightMode.LAND,) and \
                self.last_ref[REF_POS + 2] < -LANDED_ALTITUDE_M:
            on_ground = False  # asked to be up: lifting off, not landed
        if on_ground and not self.landed:
            self.landed = True
            self._landed_since_s = self.sim_t_s
            if self.armed:
                self.say("landed", 6)
        elif not on_ground and self.landed:
            self.landed = False
            self._landed_since_s = None
        if (self.armed and self.landed and self.mode == FlightMode.LAND
                and self._landed_since_s is not None
                and self.sim_t_s - self._landed_since_s >= self.parameters["COM_DISARM_LAND"]):
            self._disarm("landed: disarmed")

    def control(self) -> np.ndarray:
        """Motor commands for this control period (zeros when disarmed or without state)."""
        if not self.armed or self.measurement is None or not self.sim_link_ok:
            self._shaped = None
            self.last_commands = np.zeros(4)
            return self.last_commands
        ref, position_mode, thrust_n = self._reference()
        entries = self.perturbations.entries
        kick = np.array(kick_at(entries, self.sim_t_s)) if entries else np.zeros(2)
        self.last_ref, self.last_kick = ref, kick
        # Flights from tools limit the total tilt (PX4's MPC_TILTMAX_AIR); the paper's
        # reference keeps the per-axis clip it is tuned with.
        self.last_commands = self.controller.step(
            self.measurement, ref, position_mode, kick, thrust_n,
            self.mode != FlightMode.REFERENCE)
        return self.last_commands

    def _reference(self) -> tuple[np.ndarray, bool, float]:
        """This period's reference, whether the position loop is on, and a collective
        thrust [N] that replaces the altitude loop (NaN: it does not)."""
        if self.mode == FlightMode.REFERENCE:
            self._shaped = None
            t = self.sim_t_s - self.reference_start_s
            return self.reference.at(t), self.reference.position_mode, math.nan
        if self.attitude_target is not None and self.mode not in (
                FlightMode.HOLD, FlightMode.LAND, FlightMode.TAKEOFF):
            return self._attitude_reference(self.attitude_target)
        if self._shaped != "translation":
            m = self.measurement
            self.shaper.reset(m[MEASUREMENT.position_ned_m], m[MEASUREMENT.velocity_ned_mps],
                              m[MEAS_YAW])
            self._shaped = "translation"
        p = self.parameters
        limits = self.limits
        if self.takeoff_altitude_m is not None:
            limits = limits._replace(z_vel_max_up_mps=min(limits.z_vel_max_up_mps,
                                                          p["MPC_TKO_SPEED"]))
        elif self.mode == FlightMode.LAND:
            limits = limits._replace(z_vel_max_dn_mps=p["MPC_LAND_SPEED"])
        ref = self.shaper.step(self.setpoint, limits, self.period_s)
        if self.takeoff_altitude_m is not None and \
                abs(self.measurement[MEAS_Z] + self.takeoff_altitude_m) < TAKEOFF_REACHED_M:
            self.say("take-off complete")
            self.takeoff_altitude_m = None
            if self.mode == FlightMode.TAKEOFF:
                target = self.setpoint  # hold the take-off altitude, not where it is now
                self._enter(FlightMode.HOLD)
                self.setpoint = target
        return ref, True, math.nan

    def _attitude_reference(self, target: AttitudeTarget) -> tuple[np.ndarray, bool, float]:
        m = self.measurement
        if self._shaped != "attitude":
            self.shaper.reset_attitude(m[MEASUREMENT.euler_rad], m[MEASUREMENT.euler_rate_rad_s])
            self._shaped = "attitude"
        p = self.parameters
        ref = self.shaper.step_attitude(
            target.euler_rad, self.limits,
            (p["CMDF_OMEGA"], p["CMDF_ZETA"], p["CMDF_RATE_MAX"], p["CMDF_ACC_MAX"]),
            self.period_s)
        ref[REF_POS:REF_POS + 3] = m[MEASUREMENT.position_ned_m]
        if math.isfinite(target.thrust_fraction):
            return ref, False, target.thrust_fraction * max_thrust_n(self.controller.airframe)
        target.altitude_ref_ned_m -= target.climb_rate_mps * self.period_s
        ref[REF_POS + 2] = target.altitude_ref_ned_m
        ref[REF_VEL + 2] = -target.climb_rate_mps
        return ref, False, math.nan

    def step(self, sim_t_s: float, measurement: np.ndarray) -> np.ndarray:
        """One control period: take the sample, then compute the motor commands."""
        self.sample(sim_t_s, measurement)
        return self.control()
