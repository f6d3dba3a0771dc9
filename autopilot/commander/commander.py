"""The vehicle's commander: arming and modes, and the parts it drives.

* :class:`~autopilot.commander.land_detector.LandDetector`: on the ground or not;
* :class:`~autopilot.commander.failsafe.LinkWatch`: the ground station and the setpoint stream;
* :class:`~autopilot.flight_tasks.setpoints.FlightTasks`: setpoints, take-off, landing, shaping;
* the controller, fed the paper's reference or a flight task's.

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

import numpy as np

from autopilot.commander.failsafe import (
    GCS_LOSS_ACTIONS,
    MANUAL_LOSS_ACTIONS,
    LinkWatch,
    offboard_loss_action,
)
from autopilot.commander.land_detector import LANDED_ALTITUDE_M, LANDED_SPEED_MPS, LandDetector
from autopilot.flight_tasks import manual
from autopilot.flight_tasks.reference import Reference
from autopilot.flight_tasks.setpoints import (
    AttitudeTarget,
    FlightTasks,
    checked_attitude_target,
    checked_position_setpoint,
)
from autopilot.flight_tasks.shaping import Setpoint, ShapingLimits, limits_from_parameters
from autopilot.navigator.geofence import breach, zones_from_items
from autopilot.navigator.mission_runner import LAND_DOWN_M, Goal, MissionRunner, ReturnToLaunch
from autopilot.navigator.mission_store import FENCE, MAX_SPEED_MPS, MISSION, MissionStore
from autopilot.parameters import validate_parameters
from autopilot.refusal import RefusedError
from contracts.airframe import max_thrust_n
from contracts.frames import wrap_pi
from contracts.modes import MANUAL_MODES, FlightMode
from contracts.perturbation_book import PerturbationBook
from contracts.perturbations import Perturbation, kick_at
from contracts.telemetry import AUTOPILOT
from contracts.vectors import MEAS_VZ, MEAS_YAW, MEAS_Z, MEASUREMENT, REF_POS, REF_SIZE

__all__ = ["LANDED_ALTITUDE_M", "LANDED_SPEED_MPS", "TAKEOFF_REACHED_M", "RefusedError",
           "Commander"]

TAKEOFF_REACHED_M = 0.1
ARMABLE_MODES = (FlightMode.HOLD, FlightMode.GUIDED, FlightMode.OFFBOARD, FlightMode.TAKEOFF,
                 FlightMode.MISSION, *MANUAL_MODES)
TOOL_SETPOINT_MODES = (FlightMode.OFFBOARD, FlightMode.GUIDED)  # fly streamed setpoints
NAVIGATOR_MODES = (FlightMode.MISSION, FlightMode.RTL)  # fly the navigator's goals


# GF_ACTION -> the mode a breach puts the vehicle in (None: a warning only).
GEOFENCE_ACTIONS = {0: None, 1: None, 2: FlightMode.HOLD, 3: FlightMode.RTL,
                    5: FlightMode.LAND}


class Commander:
    """Arming state, mode, failsafes, and the controller they feed."""

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
        self.mode = self._idle_mode()
        self.tasks = FlightTasks()
        self.land_detector = LandDetector()
        self.links = LinkWatch()
        self.measurement: np.ndarray | None = None
        self.sim_t_s = 0.0
        self.reference_start_s = 0.0
        self.takeoff_altitude_m: float | None = None  # climbing to it
        self.failsafe: str | None = None
        self.messages: list[tuple[int, str]] = []  # (MAV_SEVERITY, text) for STATUSTEXT
        self.sim_link_ok = False
        # Why the state is not good enough to arm on (the estimator's reason), None if it is.
        self.navigation_problem: str | None = None
        self.estimator_status = None  # EstimatorStatus when flying on the estimator
        self.mission = MissionStore()  # mission, fence and rally lists, kept across modes
        self.navigator: MissionRunner | None = None  # the mission being flown (or paused)
        self._current_shown = 0  # the current item as the navigator last set it
        self.mission_complete = False
        self.returning: ReturnToLaunch | None = None  # AUTO.RTL's phases
        self.reached: list[int] = []  # mission items reached, for MISSION_ITEM_REACHED
        self.hold_speed_mps = math.nan  # a go-to's speed (DO_REPOSITION), NaN: the limit
        self.sticks = manual.Sticks()  # the newest MANUAL_CONTROL
        self._stick_hold = [False, False, False]  # POSCTL: horizontal, vertical, yaw held
        self.fence_breach: str | None = None  # why the vehicle is outside its fence
        self._fence_of: tuple | None = None  # the fence list the zones were built from
        self._fence_zones: tuple = ()
        self.last_ref = np.zeros(REF_SIZE)
        self.last_kick = np.zeros(2)
        self.last_commands = np.zeros(4)

    def _idle_mode(self) -> FlightMode:
        return FlightMode.GUIDED if self.flavour == "ardupilot" else FlightMode.HOLD

    # -- what the parts hold, as tools and logs read it -----------------------------------
    @property
    def setpoint(self) -> Setpoint:
        return self.tasks.setpoint

    @property
    def attitude_target(self) -> AttitudeTarget | None:
        return self.tasks.attitude_target

    @property
    def landed(self) -> bool:
        return self.land_detector.landed

    @property
    def gcs_lost(self) -> bool:
        return self.links.gcs_lost

    @property
    def gcs_heard_s(self) -> float | None:
        return self.links.gcs_heard_s

    @property
    def setpoint_heard_s(self) -> float | None:
        return self.links.setpoint_heard_s

    @property
    def altitude_m(self) -> float:
        return 0.0 if self.measurement is None else -float(self.measurement[MEAS_Z])

    @property
    def heading_rad(self) -> float:
        """The vehicle's yaw now (0 before any state arrived)."""
        return 0.0 if self.measurement is None else wrap_pi(float(self.measurement[MEAS_YAW]))

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

    # -- commands ------------------------------------------------------------------------
    def arm(self, link_t_s: float) -> None:
        if self.armed:
            return
        if self.navigation_problem is not None:
            raise RefusedError(f"arming denied: {self.navigation_problem}", temporary=True)
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
        self.tasks.shaped = None
        self.last_ref = np.zeros(REF_SIZE)
        if self.mode != FlightMode.OFFBOARD:
            self.tasks.hold_here(self.measurement, self.limits)
        else:
            self.tasks.apply_streamed(self.measurement)
        self.land_detector.set(self.landed, self.sim_t_s)
        if self.mode == FlightMode.MISSION:
            self._start_mission()

    def arm_in_reference(self) -> None:
        """Scenario runs: fly the reference from the first sample, wherever the vehicle is."""
        if self.reference is None:
            raise RefusedError("no reference generator configured")
        self.controller = self._make_controller(self.parameters)
        self.armed = True
        self.mode = FlightMode.REFERENCE
        self.reference_start_s = self.sim_t_s
        self.land_detector.landed = False

    def new_controller(self) -> object:
        """A controller as arming makes one (the process warms one up before its loop)."""
        return self._make_controller(self.parameters)

    def disarm(self, force: bool = False) -> None:
        if not self.armed:
            return
        if not self.landed and not force:
            raise RefusedError("disarming denied: in the air (force with param2 21196)")
        self._disarm("disarmed")

    def _disarm(self, text: str) -> None:
        self.armed = False
        self.tasks.shaped = None
        self.takeoff_altitude_m = None
        self.returning = None
        if self.navigator is not None and (self.navigator.landing or self.navigator.finished):
            self._mission_done()
        if self.mode in (FlightMode.LAND, FlightMode.TAKEOFF, FlightMode.REFERENCE,
                         *NAVIGATOR_MODES):
            self.mode = self._idle_mode()
        self.say(text)

    def _mission_done(self) -> None:
        """A mission flown to its end: the next start begins again at its first item."""
        self.navigator = None
        self.mission_complete = False
        self.mission.current = 0

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
        self.tasks.hold_here(self.measurement, self.limits)
        self.tasks.setpoint.position_ned_m[2] = -alt
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
        if mode == FlightMode.MISSION and not self.mission.lists[MISSION]:
            raise RefusedError("mission denied: no mission uploaded")
        if mode == FlightMode.RTL and (not self.armed or self.landed):
            raise RefusedError("return denied: not in the air", temporary=True)
        if mode in MANUAL_MODES and not self.manual_streaming(link_t_s):
            raise RefusedError(f"{mode.value} denied: no manual control input", temporary=True)
        self._enter(mode)

    def _enter(self, mode: FlightMode) -> None:
        previous = self.mode
        self.mode = mode
        self.takeoff_altitude_m = None
        self.hold_speed_mps = math.nan
        self.returning = None
        if mode in (FlightMode.HOLD, FlightMode.LAND, *MANUAL_MODES) or (
                mode == FlightMode.GUIDED and previous != FlightMode.OFFBOARD):
            self.tasks.hold_here(self.measurement, self.limits)
        self._stick_hold = [False, False, False]
        if mode == FlightMode.MISSION and self.armed:
            self._start_mission()
        if mode == FlightMode.RTL:
            self.returning = ReturnToLaunch(self.parameters)
            self.returning.start(self._stopping_point(), self.heading_rad)
        if mode == FlightMode.LAND:
            self.tasks.setpoint.position_ned_m[2] = LAND_DOWN_M
        if mode == FlightMode.OFFBOARD:
            self.tasks.apply_streamed(self.measurement)
        if mode == FlightMode.REFERENCE:
            self.reference_start_s = self.sim_t_s
        self.say(f"mode {mode.value}")

    # -- missions, return and go-to -----------------------------------------------------
    def start_mission(self, first_seq: int, link_t_s: float) -> None:
        """MAV_CMD_MISSION_START: fly the mission from item ``first_seq``."""
        items = self.mission.lists[MISSION]
        if not items:
            raise RefusedError("mission denied: no mission uploaded")
        if not 0 <= first_seq < len(items):
            raise RefusedError(f"mission start: no item {first_seq} (the mission has "
                               f"{len(items)})")
        self.mission.current = first_seq
        self.navigator, self.mission_complete = None, False
        if self.mode == FlightMode.MISSION:
            self._start_mission()
        else:
            self.set_mode(FlightMode.MISSION, link_t_s)

    def _start_mission(self) -> None:
        """Begin or resume the stored mission at its current item (a mission flown to its
        end begins again)."""
        items = self.mission.lists[MISSION]
        nav = self.navigator
        if self.mission_complete or self.mission.current >= len(items) or nav is None or \
                nav.items is not items:  # from the start, with fresh jump counts and speed
            if self.mission_complete or self.mission.current >= len(items):
                self.mission.current = 0
            self.navigator = MissionRunner(items, self.parameters)
        self.mission_complete = False  # (resuming keeps the jump counts and the speed)
        self.navigator.start(self.mission.current, self._stopping_point(), self.heading_rad,
                             self.landed, self.parameters["MIS_TAKEOFF_ALT"])
        self._navigator_events()

    def _stopping_point(self) -> np.ndarray:
        return self.tasks.stopping_point(self.measurement, self.limits)

    def _navigator_events(self) -> None:
        nav = self.navigator
        self.mission.current = nav.seq if nav.seq < len(nav.items) else len(nav.items) - 1
        self._current_shown = self.mission.current
        while nav.events:
            event = nav.events.pop(0)
            if event[0] == "reached":
                self.reached.append(event[1])
            elif event[0] == "finished":
                self.mission_complete = True
                self.say(event[1])
            elif event[0] == "rtl" and self.mode == FlightMode.MISSION:
                self.mission_complete = True
                self.say("mission: returning to launch")
                self._enter(FlightMode.RTL)

    def reposition(self, target_ned_m: np.ndarray, yaw_rad: float, speed_mps: float) -> None:
        """MAV_CMD_DO_REPOSITION: fly to a position (NaN: keep that coordinate) and hold
        there, in HOLD (PX4's AUTO.LOITER)."""
        if not self.armed or self.landed:
            raise RefusedError("go-to denied: not in the air", temporary=True)
        values = (*target_ned_m, yaw_rad, speed_mps)
        if any(math.isinf(v) for v in values):
            raise RefusedError("go-to values must be finite or NaN")
        if math.isfinite(speed_mps) and not 0 < speed_mps <= self.parameters["MPC_XY_VEL_MAX"]:
            speed_mps = math.nan  # -1 (the default speed) or beyond the limit
        held = self.tasks.setpoint.position_ned_m
        # What the tool leaves out stays as it is: the held position in HOLD, else the
        # point where the vehicle can stop.
        here = held if self.mode == FlightMode.HOLD and np.all(np.isfinite(held)) \
            else self._stopping_point()
        target = np.where(np.isfinite(target_ned_m), target_ned_m, here)
        if np.any(np.abs(target) > 1000.0):
            raise RefusedError("go-to position is more than 1 km from home")
        if self.mode != FlightMode.HOLD:
            self._enter(FlightMode.HOLD)
        yaw = yaw_rad if math.isfinite(yaw_rad) else self.tasks.setpoint.yaw_rad
        self.tasks.setpoint = Setpoint.hold(target, yaw)
        self.hold_speed_mps = speed_mps
        self.say(f"going to {target[0]:.1f} N {target[1]:.1f} E {-target[2]:.1f} m up")

    def change_speed(self, speed_mps: float) -> None:
        """MAV_CMD_DO_CHANGE_SPEED in flight: the mission's speed and a go-to's (-1: no
        change)."""
        if speed_mps == -1.0:
            return
        if not (math.isfinite(speed_mps) and 0.0 < speed_mps <= MAX_SPEED_MPS):
            raise RefusedError(f"speed {speed_mps:g} m/s is outside (0, {MAX_SPEED_MPS:g}]")
        if self.navigator is not None:
            self.navigator.speed_mps = speed_mps
        if self.mode == FlightMode.HOLD:
            self.hold_speed_mps = speed_mps
        self.say(f"speed {speed_mps:.1f} m/s")

    @property
    def mission_active(self) -> bool:
        return self.mode == FlightMode.MISSION and self.armed and self.navigator is not None

    @property
    def mission_state(self) -> str:
        """none, not started, active, paused or complete (MISSION_CURRENT's states)."""
        items = self.mission.lists[MISSION]
        if not items:
            return "none"
        if self.mission_complete:
            return "complete"
        if self.navigator is None or self.navigator.items is not items:
            return "not started"
        return "active" if self.mission_active else "paused"

    # -- setpoints from tools ----------------------------------------------------------
    def setpoints_streaming(self, link_t_s: float) -> bool:
        return self.links.setpoints_streaming(link_t_s, self.parameters["COM_OF_LOSS_T"])

    def position_setpoint(self, link_t_s: float, setpoint: Setpoint) -> None:
        """A local NED setpoint (NaN for what the tool left out); checked before anything
        changes. Per axis group a position (velocity and acceleration then feed-forward)
        or a velocity; a yaw or a yaw rate (docs/mavlink.md)."""
        checked = checked_position_setpoint(setpoint)
        self.links.setpoint_heard(link_t_s)
        self.tasks.stream_position(link_t_s, checked)
        if self.mode in TOOL_SETPOINT_MODES:
            self.tasks.apply_streamed(self.measurement)

    def attitude_setpoint(self, link_t_s: float, quaternion: tuple | None,
                          thrust: float | None) -> None:
        """An attitude setpoint, thrust as the flavour reads it (flight_tasks.py)."""
        target = checked_attitude_target(quaternion, thrust, self.flavour,
                                         self.parameters["MPC_TKO_SPEED"])
        self.links.setpoint_heard(link_t_s)
        self.tasks.streamed = target
        if self.mode in TOOL_SETPOINT_MODES:
            self.tasks.apply_streamed(self.measurement)

    # -- manual control ------------------------------------------------------------------
    def manual_streaming(self, link_t_s: float) -> bool:
        return self.links.manual_streaming(link_t_s, self.parameters["COM_RC_LOSS_T"])

    def manual_input(self, link_t_s: float, sticks: manual.Sticks) -> None:
        """MANUAL_CONTROL's sticks (checked by manual.sticks_from_manual_control)."""
        self.links.manual_heard_s = link_t_s
        self.sticks = sticks

    def _manual_reference(self, limits: ShapingLimits) -> tuple[np.ndarray, bool, float]:
        """POSCTL through the translation shaper; ALTCTL and STABILIZED through the
        attitude shaper, as an attitude setpoint from a tool would."""
        p, sticks = self.parameters, self.sticks
        if self.mode == FlightMode.POSCTL:
            self.tasks.start_translation(self.measurement)
            shaper = self.tasks.shaper
            self._stick_hold = manual.position_control(
                self.tasks.setpoint, sticks, shaper.yaw_rad, shaper.stopping_point(limits),
                self._stick_hold, p)
            return self.tasks.translation_reference(self.measurement, limits,
                                                    self.period_s), True, math.nan
        af = self.controller.airframe
        hover = af.mass_kg * af.gravity_mps2 / max_thrust_n(af) \
            if self.mode == FlightMode.STABILIZED else None
        self.tasks.streamed = manual.attitude_control(sticks, p, hover)
        self.tasks.apply_streamed(self.measurement)
        return self._attitude_reference(limits)

    def _attitude_reference(self, limits: ShapingLimits) -> tuple[np.ndarray, bool, float]:
        p = self.parameters
        return self.tasks.attitude_reference(
            self.measurement, limits,
            (p["CMDF_OMEGA"], p["CMDF_ZETA"], p["CMDF_RATE_MAX"], p["CMDF_ACC_MAX"]),
            self.period_s, max_thrust_n(self.controller.airframe))

    # -- links and failsafes -------------------------------------------------------------
    def gcs_heartbeat(self, link_t_s: float) -> None:
        if self.links.gcs_heartbeat(link_t_s):
            self.say("ground station link regained", 5)

    def check_links(self, link_t_s: float) -> None:
        """Failsafes timed on the link clock: ground station and setpoint stream."""
        p = self.parameters
        if self.links.gcs_lost_now(link_t_s, p["COM_DL_LOSS_T"]):
            self._failsafe("ground station lost", GCS_LOSS_ACTIONS[int(p["NAV_DLL_ACT"])])
        if self.mode == FlightMode.OFFBOARD and not self.setpoints_streaming(link_t_s):
            if self.armed:
                self._failsafe("offboard setpoints lost", offboard_loss_action(p["COM_OBL_ACT"]))
            else:
                self.mode = FlightMode.HOLD
        if self.mode in MANUAL_MODES and not self.manual_streaming(link_t_s):
            if self.armed:
                self._failsafe("manual control lost", MANUAL_LOSS_ACTIONS[int(p["NAV_RCL_ACT"])])
            else:
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
        if self.armed and not self.landed and self.mode != FlightMode.REFERENCE:
            self._check_geofence()

    @property
    def landing(self) -> bool:
        """Descending to land: LAND, the landing of a mission or a return, or the throttle
        stick down in a manual mode (each disarms COM_DISARM_LAND after touchdown)."""
        return self.mode == FlightMode.LAND or (
            self.mode == FlightMode.MISSION and self.navigator is not None
            and self.navigator.landing) or (
            self.mode == FlightMode.RTL and self.returning is not None
            and self.returning.landing) or (
            self.mode in MANUAL_MODES and manual.climb_stick(self.sticks.throttle,
                                                             self.parameters) < 0.0)

    def _check_geofence(self) -> None:
        """GF_ACTION on crossing out of the fence (once per breach), as PX4: a STATUSTEXT,
        and hold or land."""
        fence = self.mission.lists[FENCE]
        if fence is not self._fence_of:
            self._fence_of, self._fence_zones = fence, zones_from_items(fence)
        p = self.parameters
        reason = breach(self.measurement[MEASUREMENT.position_ned_m], self._fence_zones,
                        p["GF_MAX_HOR_DIST"], p["GF_MAX_VER_DIST"])
        if reason is None or self.fence_breach is not None:
            self.fence_breach = reason
            return
        self.fence_breach = reason
        action = GEOFENCE_ACTIONS[int(p["GF_ACTION"])]
        if action is None:
            if p["GF_ACTION"] == 1:  # a warning, not a failsafe
                self.say(f"geofence: {reason}", 4)
            return
        self._failsafe(f"geofence: {reason}", action)

    def _lifting_off(self) -> bool:
        """Armed and asked to be up: taking off, or a reference above the ground (not
        while landing)."""
        return self.armed and (
            self.mode == FlightMode.TAKEOFF or self.takeoff_altitude_m is not None
            or (not self.landing
                and self.last_ref[REF_POS + 2] < -LANDED_ALTITUDE_M))

    def _detect_landing(self) -> None:
        m = self.measurement
        change = self.land_detector.update(self.sim_t_s, -m[MEAS_Z], m[MEAS_VZ],
                                           self._lifting_off())
        if change == "landed" and self.armed:
            self.say("landed", 6)
        if (self.armed and self.landing and self.landed
                and self.land_detector.landed_since_s is not None
                and self.land_detector.landed_for_s(self.sim_t_s)
                >= self.parameters["COM_DISARM_LAND"]):
            self._disarm("landed: disarmed")

    def control(self) -> np.ndarray:
        """Motor commands for this control period (zeros when disarmed or without state)."""
        if not self.armed or self.measurement is None or not self.sim_link_ok:
            self.tasks.shaped = None
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
            self.tasks.shaped = None
            t = self.sim_t_s - self.reference_start_s
            return self.reference.at(t), self.reference.position_mode, math.nan
        p = self.parameters
        if self.mode in MANUAL_MODES:
            return self._manual_reference(self.limits)
        if self.tasks.attitude_target is not None and self.mode in TOOL_SETPOINT_MODES:
            return self._attitude_reference(self.limits)
        limits = self.limits
        vertical = "land" if self.mode == FlightMode.LAND else ""
        speed = self.hold_speed_mps if self.mode == FlightMode.HOLD else math.nan
        if self.mode in NAVIGATOR_MODES:
            goal = self._navigator_goal()
            self.tasks.setpoint = goal.setpoint
            speed, vertical = goal.speed_mps, goal.vertical
        if math.isfinite(speed):
            limits = limits._replace(xy_vel_max_mps=min(limits.xy_vel_max_mps, speed))
        if self.takeoff_altitude_m is not None or vertical == "takeoff":
            limits = limits._replace(z_vel_max_up_mps=min(limits.z_vel_max_up_mps,
                                                          p["MPC_TKO_SPEED"]))
        elif vertical == "land":
            limits = limits._replace(z_vel_max_dn_mps=p["MPC_LAND_SPEED"])
        ref = self.tasks.translation_reference(self.measurement, limits, self.period_s)
        if self.takeoff_altitude_m is not None and \
                abs(self.measurement[MEAS_Z] + self.takeoff_altitude_m) < TAKEOFF_REACHED_M:
            self.say("take-off complete")
            self.takeoff_altitude_m = None
            if self.mode == FlightMode.TAKEOFF:
                target = self.tasks.setpoint  # hold the take-off altitude, not where it is
                self._enter(FlightMode.HOLD)
                self.tasks.setpoint = target
        return ref, True, math.nan

    def _navigator_goal(self) -> Goal:
        """The mission's or the return's goal for this period."""
        here = self.measurement[MEASUREMENT.position_ned_m]
        reference = self.tasks.shaper.position_ned_m if self.tasks.shaped == "translation" \
            else here
        # Parameters changed in flight apply at once.
        if self.mode == FlightMode.RTL:
            self.returning.parameters = self.parameters
            return self.returning.step(here, reference)
        self.navigator.parameters = self.parameters
        if self.navigator.items is not self.mission.lists[MISSION]:
            # A new mission (or none) uploaded in flight: fly it from its first item, as
            # PX4 does; without one, hold.
            if not self.mission.lists[MISSION]:
                self.say("mission cleared: holding", 4)
                self.navigator = None
                self._enter(FlightMode.HOLD)
                return Goal(self.tasks.setpoint)
            self._start_mission()
        elif self.mission.current != self._current_shown:
            self._start_mission()  # a tool set the current item: go on from there
        goal = self.navigator.step(self.sim_t_s, here, reference)
        self._navigator_events()
        if self.mode == FlightMode.RTL:  # the mission handed over to a return
            return self.returning.step(here, reference)
        return goal

    def step(self, sim_t_s: float, measurement: np.ndarray) -> np.ndarray:
        """One control period: take the sample, then compute the motor commands."""
        self.sample(sim_t_s, measurement)
        return self.control()
