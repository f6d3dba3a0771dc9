"""The vehicle's commander: arming, modes and failsafes, routed by the mode table.

* the mode table (autopilot/commander/modes.py) says, per mode, what it allows and needs,
  which flight task (autopilot/flight_tasks/) produces its reference and how it lands;
* :class:`~autopilot.commander.land_detector.LandDetector`: on the ground or not;
* :class:`~autopilot.commander.failsafe.Failsafes`: the ground station, input streams and
  fence, deciding from a snapshot of the vehicle; :meth:`Commander.apply_failsafe` carries
  the decisions out;
* :class:`~autopilot.commander.inputs.ToolInputs`: the setpoints and sticks tools stream;
* :class:`~autopilot.commander.auto_commands.AutoCommands`: mission start, go-to, speed;
* :class:`~autopilot.navigator.navigator.Navigator`: the mission lists and the mission;
* the controller (autopilot/control/controller.py), fed the current task's reference.

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

from autopilot.commander.auto_commands import AutoCommands
from autopilot.commander.failsafe import (
    FailsafeDecision,
    Failsafes,
    FailsafeView,
    Response,
    decide,
)
from autopilot.commander.failures import InjectedFailures
from autopilot.commander.inputs import ToolInputs
from autopilot.commander.land_detector import LANDED_ALTITUDE_M, LandDetector
from autopilot.commander.modes import MODES, EntryView, ModeRow
from autopilot.commander.personality import PERSONALITIES, ArmingView, Personality
from autopilot.control.controller import Controller
from autopilot.flight_tasks.manager import FlightControl
from autopilot.flight_tasks.task import FlightTask, Shaped, TaskEnv, TaskState
from autopilot.navigator.home import Places
from autopilot.navigator.mission_store import FENCE, MISSION, MissionStore
from autopilot.navigator.navigator import Navigator
from autopilot.parameters import validate_parameters
from autopilot.refusal import RefusedError
from autopilot.trajectories import Reference
from contracts.airframe import max_thrust_n
from contracts.frames import Home
from contracts.modes import FlightMode
from contracts.perturbation_book import PerturbationBook
from contracts.perturbations import Perturbation
from contracts.telemetry import AUTOPILOT
from contracts.vectors import MEAS_VZ, MEAS_Z, MEASUREMENT, REF_POS, REF_SIZE


class Commander:
    """Arming state, mode, failsafes, and the controller they feed."""

    def __init__(
        self,
        make_controller: Callable[[dict[str, float]], Controller],
        period_s: float,
        parameters: dict[str, float] | None = None,
        reference: Reference | None = None,
        schedule: tuple[Perturbation, ...] = (),
        flavour: str = "px4",
    ) -> None:
        self.make_controller = make_controller
        self.period_s = period_s
        params = validate_parameters(parameters or {})
        self.controller = make_controller(params)
        af = self.controller.airframe
        thrust_n = max_thrust_n(af)
        self.land_detector = LandDetector()
        self.state = TaskState(period_s, params, thrust_n,
                               af.mass_kg * af.gravity_mps2 / thrust_n, self.land_detector)
        self.reference = reference
        self.flavour = flavour
        self.personality: Personality = PERSONALITIES[flavour]  # its rules and words
        self.armed = False
        self.mode = self.idle_mode = self.personality.boot_mode
        self.failsafes = Failsafes()
        self.links = self.failsafes.links
        self.failsafe: str | None = None
        self.messages: list[tuple[int, str]] = []  # (MAV_SEVERITY, text) for STATUSTEXT
        self.failures = InjectedFailures()  # from ground tools (MAV_CMD_INJECT_FAILURE)
        self.sim_link_ok = False
        # The local frame's origin on Earth (given or from the simulator's first position;
        # PX4's default until then) and home: navigator.places (autopilot/navigator/home.py).
        self.home_known = False
        # Why the state is not good enough to arm on (the estimator's reason), None if it is.
        self.navigation_problem: str | None = None
        self.estimator_status = None  # EstimatorStatus when flying on the estimator
        self.navigator = Navigator(self.say, copter_rules=flavour == "ardupilot")
        env = TaskEnv(self.state, self.navigator, reference, self.switch_to, self.say)
        self.tasks: dict[FlightMode, FlightTask] = {m: row.task(env) for m, row in MODES.items()}
        # What tools stream (setpoints, sticks, a follow target).
        self.inputs = ToolInputs(self.links, self.state, self.tasks[FlightMode.FOLLOW_TARGET],
                                 flavour, lambda: self.row.follows_setpoints, self.say,
                                 self.personality.setpoints_in_guided_only)
        # Where the automatic modes fly (mission start, go-to, speed).
        self.auto = AutoCommands(self, self.navigator, self.tasks[FlightMode.HOLD],
                                 self.tasks[FlightMode.MISSION], self.state, self.say,
                                 self.tasks[FlightMode.GUIDED])
        # Reference kicks (sim time), from the command line and from Zenoh requests.
        self.flight = FlightControl(self.state, self.tasks, self.controller,
                                    PerturbationBook(AUTOPILOT, schedule))

    # -- what the parts hold, as tools and logs read it -----------------------------------
    row: ModeRow = property(lambda self: MODES[self.mode])
    reference_start_s: float = property(lambda self: self.tasks[FlightMode.REFERENCE].start_s)
    task: FlightTask = property(lambda self: self.tasks[self.mode])

    parameters = property(lambda self: self.state.parameters)
    measurement = property(lambda self: self.state.measurement)
    sim_t_s = property(lambda self: self.state.sim_t_s)
    setpoint = property(lambda self: self.state.setpoint)
    heading_rad = property(lambda self: self.state.heading_rad)
    takeoff_altitude_m = property(lambda self: self.state.takeoff_altitude_m)
    landed = property(lambda self: self.land_detector.landed)
    gcs_lost = property(lambda self: self.links.gcs_lost)
    mission: MissionStore = property(lambda self: self.navigator.store)
    reached = property(lambda self: self.navigator.reached)
    perturbations = property(lambda self: self.flight.perturbations)
    last_commands = property(lambda self: self.flight.last_commands)
    rc_channels_pwm: tuple[int, ...] = property(lambda self: self.inputs.rc.pwm)

    @property
    def landing(self) -> bool:
        """Descending to land, as the mode's task says (disarms after touchdown)."""
        return self.task.landing

    @property
    def mission_active(self) -> bool:
        return self.mode is FlightMode.MISSION and self.armed and \
            self.navigator.runner is not None

    @property
    def mission_state(self) -> str:
        """none, not started, active, paused or complete (MISSION_CURRENT's states)."""
        return self.navigator.state(self.mission_active)

    def say(self, text: str, severity: int = 6) -> None:
        """Queue a STATUSTEXT (severity 3 error ... 6 info), in chunks up to 200 characters."""
        self.messages.append((severity, text[:200]))

    def inject_failure(self, unit: float, kind: float, instance: float) -> None:
        """MAV_CMD_INJECT_FAILURE (autopilot/commander/failures.py): refused unless
        SYS_FAILURE_EN is 1; announced when done."""
        enabled = self.parameters["SYS_FAILURE_EN"] == 1.0
        self.say(self.failures.inject(enabled, unit, kind, instance), 4)

    def set_parameter(self, name: str, value: float) -> None:
        """Change one parameter; it takes effect at the next control step."""
        try:
            updated = validate_parameters({**self.parameters, name: value})
        except ValueError as exc:
            raise RefusedError(str(exc)) from None
        self.state.set_parameters(updated)
        self.controller.apply_parameters(updated)

    # -- arming ----------------------------------------------------------------------------
    def arm(self, link_t_s: float, force: bool = False) -> None:
        if self.armed:
            return
        row = self.row
        self.personality.check_arming(self.mode, row, ArmingView(
            self.navigation_problem, self.sim_link_ok and self.measurement is not None,
            self.landed, force,
            row.stream is not None and self.inputs.streaming(row.stream, link_t_s)))
        self.controller.reset()
        self.armed = True
        self.failsafe = None  # a new flight: what went wrong before is over
        self.state.shaped = Shaped.NONE
        self.flight.last_ref = np.zeros(REF_SIZE)
        self.task.on_arm()
        self.land_detector.set(self.landed, self.sim_t_s)
        self.say(self.personality.armed_text)

    def arm_in_reference(self) -> None:
        """Scenario runs: fly the reference from the first sample, wherever the vehicle is."""
        if self.reference is None:
            raise RefusedError("no reference generator configured")
        self.controller.reset()
        self.armed = True
        self.mode = FlightMode.REFERENCE
        self.tasks[FlightMode.REFERENCE].begin()
        self.land_detector.landed = False

    def disarm(self, force: bool = False) -> None:
        if not self.armed:
            return
        if not self.landed and not force:
            raise RefusedError("disarming denied: in the air (force with param2 21196)")
        self.end_flight(self.personality.disarmed_text)

    def terminate(self) -> None:
        """Flight termination: motors off and disarmed at once, in the air too."""
        if self.armed:
            self.failsafe = "flight terminated"
            self.end_flight(self.personality.terminated_text)

    def end_flight(self, text: str) -> None:
        """Disarm now, saying ``text`` (on the ground, or a failsafe's last resort)."""
        self.armed = False
        self.state.shaped = Shaped.NONE
        self.state.takeoff_altitude_m = None
        self.navigator.flight_ended()
        if self.row.ends_with_flight and not self.personality.keeps_mode_on_disarm:
            self.mode = self.idle_mode
        self.say(text)

    # -- modes -----------------------------------------------------------------------------
    def takeoff(self, relative_altitude_m: float | None) -> None:
        alt = self.parameters["MIS_TAKEOFF_ALT"] if relative_altitude_m is None \
            else relative_altitude_m
        if not math.isfinite(alt) or not 0.5 <= alt <= 100.0:
            raise RefusedError(f"take-off altitude {alt:g} m is outside [0.5, 100] m")
        if not self.armed:
            raise RefusedError("take-off denied: disarmed", temporary=True)
        self.personality.check_takeoff(self.mode, self.landed)
        if self.personality.takeoff_mode is None:
            self.mode = FlightMode.TAKEOFF
        self.tasks[FlightMode.TAKEOFF].climb_to(alt)
        self.say(f"taking off to {alt:.1f} m")

    def land(self) -> None:
        if not self.armed:
            raise RefusedError("landing denied: disarmed", temporary=True)
        self.switch_to(FlightMode.LAND)

    def set_mode(self, mode: FlightMode, link_t_s: float) -> None:
        """A mode a tool asks for: its needs checked first (Copter's: when armed only)."""
        if mode == self.mode:
            return
        row = MODES[mode]
        if row.command is None and not self.armed and self.personality.any_mode_disarmed:
            self.switch_to(mode)
            return
        self.personality.check_entry(mode, row, EntryView(
            self.armed, self.landed, self.reference is not None,
            bool(self.mission.lists[MISSION])),
            row.stream is None or self.inputs.streaming(row.stream, link_t_s),
            lambda: self.navigator.check_mode_entry(mode, self.armed, self.landed))
        if row.command is not None:
            row.command(self)
            return
        self.switch_to(mode)

    def switch_to(self, mode: FlightMode) -> None:
        """Enter ``mode`` (checked already, or a failsafe's or a task's hand-over)."""
        previous = self.mode
        self.mode = mode
        self.state.takeoff_altitude_m = None
        self.tasks[mode].activate(previous, self.armed)
        if self.personality.mode_changed_text is not None:
            self.say(self.personality.mode_changed_text.format(mode=mode.value))

    # -- links and failsafes -----------------------------------------------------------------
    def check_links(self, link_t_s: float) -> None:
        """Failsafes timed on the link clock: ground station, then the mode's input stream
        (as the first may have changed the mode, the second reads the vehicle after it)."""
        self.apply_failsafe(self.failsafes.ground_station(link_t_s, self.parameters,
                                                          self.failsafe_view()))
        self.apply_failsafe(self.failsafes.input_stream(link_t_s, self.parameters,
                                                        self.failsafe_view()))

    def failsafe_view(self) -> FailsafeView:
        """The snapshot the failsafes decide on, taken when they look."""
        return FailsafeView(self.armed, self.landed, self.inputs.watched(self.row.stream))

    def apply_failsafe(self, decision: FailsafeDecision | None) -> None:
        """Carry out a failsafe's decision: the one way a failsafe changes the vehicle.
        A failsafe is remembered (``failsafe``) and said; in the air the mode changes
        through ``switch_to``; on the ground the flight ends. A stream lost while disarmed
        sets HOLD without entering it (no task activation, nothing said)."""
        if decision is None:
            return
        response, reason = decision.response, decision.reason
        if response is Response.NOTE:
            self.say(reason, 4)
            return
        if response is Response.FALL_BACK:
            if self.personality.falls_back_disarmed:
                self.mode = decision.mode
            return
        self.failsafe = reason
        if response is Response.WARN:
            self.say(reason, 4)
        elif response is Response.DISARM:
            self.end_flight(f"{reason}: disarmed on the ground")
        else:
            self.say(f"{reason}: {decision.mode.value}", 4)
            if self.mode != decision.mode:
                self.switch_to(decision.mode)

    def set_origin(self, origin: Home) -> None:
        """Where the local frame is on Earth (home with it): latitudes taken around it."""
        self.home_known, self.navigator.places = True, Places.at(origin)

    places = property(lambda self: self.navigator.places)  # origin, home (navigator/home.py)

    def position_lost(self, what: str) -> None:
        """The estimator has dead-reckoned past EKF2_NOAID_TOUT: land (PX4 descends)."""
        self.apply_failsafe(decide(what, FlightMode.LAND, self.failsafe_view()))

    def sim_link_lost(self) -> None:
        if self.sim_link_ok:
            self.sim_link_ok = False
            self.apply_failsafe(decide("simulator link lost", FlightMode.LAND,
                                       self.failsafe_view()))

    # -- the control step --------------------------------------------------------------------
    def sample(self, sim_t_s: float, measurement: np.ndarray) -> None:
        """New state from the simulator. A clock going back means a new simulator."""
        if self.measurement is not None and sim_t_s < self.sim_t_s:
            self.say("simulator restarted", 5)
            if self.armed and -measurement[MEAS_Z] < LANDED_ALTITUDE_M:
                self.end_flight("simulator restarted: disarmed on the ground")
        if not self.sim_link_ok:
            self.say("simulator link up", 6)
        self.sim_link_ok = True
        self.state.new_sample(sim_t_s, measurement)
        self._detect_landing()
        if self.armed and not self.landed and self.row.geofence:
            self.apply_failsafe(self.failsafes.fence(
                self.mission.lists[FENCE], self.places,
                self.measurement[MEASUREMENT.position_ned_m], self.parameters,
                self.failsafe_view()))

    def _detect_landing(self) -> None:
        m, s = self.measurement, self.state
        # Armed and asked to be up: taking off, or a reference above the ground.
        lifting_off = self.armed and (s.takeoff_altitude_m is not None or (
            not self.landing and self.flight.last_ref[REF_POS + 2] < -LANDED_ALTITUDE_M))
        change = self.land_detector.update(s.sim_t_s, -m[MEAS_Z], m[MEAS_VZ], lifting_off)
        if change == "landed" and self.armed:
            self.say("landed", 6)
        if (self.armed and self.landing and self.landed
                and self.land_detector.landed_since_s is not None
                and self.land_detector.landed_for_s(s.sim_t_s)
                >= self.parameters["COM_DISARM_LAND"]):
            self.end_flight(self.personality.landed_disarmed_text)

    def control(self) -> np.ndarray:
        """Motor commands for this control period (zeros when disarmed or without state)."""
        if not self.armed or self.measurement is None or not self.sim_link_ok:
            return self.flight.idle()
        return self.flight.step(lambda: self.mode, self.row.tilt_limited)

    def step(self, sim_t_s: float, measurement: np.ndarray) -> np.ndarray:
        """One control period: take the sample, then compute the motor commands."""
        self.sample(sim_t_s, measurement)
        return self.control()
