"""What every flight task is and what they share.

A flight task is one way of producing the controller's reference (PX4's flight tasks):
a held position, streamed offboard setpoints, a take-off, a mission, the sticks, the
paper's reference... The commander's mode table (autopilot/commander/modes.py) names
the task of each mode; each control period the commander asks the current mode's task
for this period's reference.

Tasks hand over to one another without a jump, so what they have in common lives in one
:class:`TaskState`: the setpoint being flown, the newest one a tool streamed, and the
setpoint shaper (autopilot/flight_tasks/shaper.py), whose reference the next task starts
from. Pure: the commander keeps the state's measurement, sim time and parameters current.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, NamedTuple, Protocol

import numpy as np

from autopilot.flight_tasks.goal import Vertical
from autopilot.flight_tasks.setpoints import AttitudeTarget
from autopilot.flight_tasks.shaper import SetpointShaper
from autopilot.flight_tasks.shaping import Setpoint, ShapingLimits, limits_from_parameters
from autopilot.flight_tasks.sticks import Sticks
from contracts.frames import wrap_pi
from contracts.modes import FlightMode
from contracts.vectors import MEAS_YAW, MEAS_Z, MEASUREMENT, REF_POS, REF_VEL

if TYPE_CHECKING:
    from autopilot.commander.land_detector import LandDetector
    from autopilot.navigator.navigator import Navigator
    from autopilot.trajectories import Reference

# The most sim time one control step advances the setpoints by: COM_SIM_LOSS_T's default.
# Sim time jumps between two steps when this process stood still while the simulator flew
# on (a stalled simulator resumes from where it stopped); longer, the link-loss failsafe
# flies. At 50 ms a 70 ms stop of this process slowed an orbit by 25 mm/s, 200 ms by
# 350 mm/s (its point fell behind by the rest); at 0.5 s, by 0.7 and 1.1 mm/s.
MAX_SETPOINT_STEP_S = 0.5
# A position setpoint's velocity / acceleration feed-forward is the setpoint's own motion:
# it applies while the streamed position moves, and lapses this long after it stops, so
# a setpoint that stands still is a place to stop at, not to fly past.
FEED_FORWARD_HOLD_S = 0.5


class Shaped(enum.Enum):
    """Which shaper path produced the last reference."""

    NONE = "none"  # none yet, or the paper's reference (not shaped)
    TRANSLATION = "translation"  # a position / velocity setpoint
    ATTITUDE = "attitude"  # an attitude target


class TaskOutput(NamedTuple):
    """A period's reference, whether the position loop is on, and a collective thrust
    [N] that replaces the altitude loop (NaN: it does not)."""

    reference: np.ndarray
    position_mode: bool = True
    thrust_n: float = math.nan


class FlightTask(Protocol):
    """One way of producing the reference; the mode table says which mode flies which."""

    def activate(self, previous: FlightMode, armed: bool) -> None:
        """The vehicle entered a mode this task flies (coming from ``previous``)."""
        ...

    def on_arm(self) -> None:
        """The vehicle armed in a mode this task flies."""
        ...

    def update(self) -> TaskOutput | None:
        """This period's reference; None when the task handed over to another mode this
        period (the commander then asks that mode's task)."""
        ...

    @property
    def landing(self) -> bool:
        """Descending to land (the commander disarms COM_DISARM_LAND after touchdown)."""
        ...


class TaskState:
    """What the flight tasks share: the vehicle's state as the commander last saw it, the
    setpoint flown, the newest one a tool streamed, and the shaper."""

    def __init__(self, period_s: float, parameters: dict[str, float], max_thrust_n: float,
                 hover_fraction: float, land_detector: LandDetector) -> None:
        self.period_s = period_s
        # Sim time since the previous control step's sample: what the setpoints advance by
        # this step. In real time a late step loses whole periods, and setpoints advanced
        # by period_s would fall behind the vehicle by them (3 lost periods slowed an
        # orbit by 30-40 mm/s for a second).
        self.step_s = period_s
        self.step_periods = 1  # how many control periods step_s spans (more: periods lost)
        self._setpoints_us: int | None = None  # the sim time they stand at [us] (None: no step)
        self._stepped_us = 0  # the sample time of the last control step [us]
        self.parameters = parameters
        self.limits: ShapingLimits = limits_from_parameters(parameters)
        self.max_thrust_n = max_thrust_n
        self.hover_fraction = hover_fraction  # thrust / maximum that holds the vehicle up
        self.measurement: np.ndarray | None = None
        self.sim_t_s = 0.0
        self.land_detector = land_detector  # the commander's: on the ground or not
        self.setpoint = Setpoint.hold((0.0, 0.0, 0.0), 0.0)
        self.attitude_target: AttitudeTarget | None = None  # bypasses the setpoint
        self.shaper = SetpointShaper()
        self.shaped = Shaped.NONE
        self.streamed: Setpoint | AttitudeTarget | None = None  # newest, before offboard
        self.sticks = Sticks()  # the newest MANUAL_CONTROL
        self.loiter_sticks = False  # HOLD flies the sticks too (ArduPilot's LOITER with RC)
        self.takeoff_altitude_m: float | None = None  # climbing to it
        self._tool_position: np.ndarray | None = None
        self._tool_position_moved_s = -math.inf

    def new_sample(self, sim_t_s: float, measurement: np.ndarray) -> None:
        """The simulator's newest state. Only a control step moves the setpoints on
        (``begin_step``): in real time every sample is taken as it arrives and the step
        takes the newest again, and a sample counted twice would leave the setpoints
        going on a period per step whatever the sim time lost."""
        self.sim_t_s = sim_t_s
        self.measurement = measurement

    def begin_step(self) -> None:
        """A control step on the newest sample: the setpoints move on from the sim time
        they stand at to the sample's, in whole microseconds (so that a lockstep step is
        period_s exactly), at most MAX_SETPOINT_STEP_S. The same sample at two steps
        moves them on by a period, made up only by a sample over a period later (the
        real-time loop does not step twice on a sample: it holds the last command). No
        sample yet: nothing moves."""
        if self.measurement is None:
            return
        now_us, period_us = round(self.sim_t_s * 1e6), round(self.period_s * 1e6)
        if self._setpoints_us is None or now_us < self._stepped_us:  # a new simulator
            ahead_us = period_us
        else:
            ahead_us = now_us - self._setpoints_us
            if ahead_us <= 0:  # the same sample again: a period ahead
                ahead_us = period_us
                now_us = self._setpoints_us + period_us
            else:  # a stall: at most the cap, and the setpoints start again from now
                ahead_us = min(ahead_us, round(MAX_SETPOINT_STEP_S * 1e6))
        self._stepped_us = round(self.sim_t_s * 1e6)
        self._setpoints_us = now_us
        self.step_s = ahead_us / 1e6
        self.step_periods = -(-ahead_us // period_us)  # control periods it spans (ceil)

    def set_parameters(self, parameters: dict[str, float]) -> None:
        self.parameters = parameters
        self.limits = limits_from_parameters(parameters)

    @property
    def landed(self) -> bool:
        return self.land_detector.landed

    @property
    def heading_rad(self) -> float:
        """The vehicle's yaw now (0 before any state arrived)."""
        m = self.measurement
        return 0.0 if m is None else wrap_pi(float(m[MEAS_YAW]))

    @property
    def position_ned_m(self) -> np.ndarray:
        return self.measurement[MEASUREMENT.position_ned_m]

    # -- setpoints -----------------------------------------------------------------------
    def hold_here(self) -> None:
        """Hold where the vehicle can stop: the shaped reference's stopping point when it
        is moving one, else the measured position; the heading it has."""
        yaw = self.shaper.yaw_rad if self.shaped is Shaped.TRANSLATION else self.heading_rad
        self.setpoint = Setpoint.hold(self.stopping_point(), yaw)
        self.attitude_target = None

    def stopping_point(self) -> np.ndarray:
        """Where the vehicle can come to rest: the shaped reference's stopping point while
        one is flown, else the measured position."""
        if self.shaped is Shaped.TRANSLATION:
            return self.shaper.stopping_point(self.limits)
        if self.measurement is None:
            return np.zeros(3)
        return self.position_ned_m.copy()

    def reference_position_ned_m(self) -> np.ndarray:
        """Where the shaped reference is (the vehicle's position when none is shaped)."""
        if self.shaped is Shaped.TRANSLATION:
            return self.shaper.position_ned_m
        return self.position_ned_m

    def reference_velocity_ned_mps(self) -> np.ndarray:
        """How the shaped reference moves (the vehicle's velocity when none is shaped)."""
        if self.shaped is Shaped.TRANSLATION:
            return self.shaper.velocity_ned_mps
        if self.measurement is None:
            return np.zeros(3)
        return self.measurement[MEASUREMENT.velocity_ned_mps]

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

    def apply_streamed(self) -> None:
        """The newest streamed setpoint becomes what the vehicle flies to."""
        streamed = self.streamed
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

    # -- references ----------------------------------------------------------------------
    def translate(self, speed_mps: float = math.nan,
                  vertical: Vertical = Vertical.CRUISE) -> TaskOutput:
        """The setpoint shaped into this period's reference, at most ``speed_mps``
        horizontally (NaN: the limit), climbing at the take-off speed while taking off
        and descending at the landing speed when landing."""
        p, limits = self.parameters, self.limits
        if math.isfinite(speed_mps):
            limits = limits._replace(xy_vel_max_mps=min(limits.xy_vel_max_mps, speed_mps))
        if self.takeoff_altitude_m is not None or vertical is Vertical.TAKEOFF:
            limits = limits._replace(z_vel_max_up_mps=min(limits.z_vel_max_up_mps,
                                                          p["MPC_TKO_SPEED"]))
        elif vertical is Vertical.LAND:
            limits = limits._replace(z_vel_max_dn_mps=p["MPC_LAND_SPEED"])
        return TaskOutput(self.shape_translation(limits))

    def shape_translation(self, limits: ShapingLimits) -> np.ndarray:
        """The setpoint through the shaper within ``limits`` (the shaper starts from the
        vehicle's own position and velocity when it takes over)."""
        self.start_translation()
        substeps = self.step_periods
        if substeps <= 1:
            return self.shaper.step(self.setpoint, limits, self.step_s)
        # Periods lost (real time): the shaper's loops are discrete, and one long step
        # is not the periods it stands for (its target, already moved on, is far ahead
        # of the reference at the start of it). The lost periods are shaped one by one,
        # towards the setpoint where its own motion had it then.
        dt = self.step_s / substeps
        for k in range(substeps - 1, 0, -1):
            self.shaper.step(self.setpoint.earlier(k * dt), limits, dt)
        return self.shaper.step(self.setpoint, limits, dt)

    def start_translation(self) -> None:
        """Start translation shaping from the vehicle's state, unless it is on already."""
        if self.shaped is not Shaped.TRANSLATION:
            m = self.measurement
            self.shaper.reset(m[MEASUREMENT.position_ned_m], m[MEASUREMENT.velocity_ned_mps],
                              m[MEAS_YAW])
            self.shaped = Shaped.TRANSLATION

    def attitude(self) -> TaskOutput:
        """The attitude target's reference, the position loop off, and a collective thrust
        replacing the altitude loop (NaN: the altitude loop runs)."""
        p, m, target = self.parameters, self.measurement, self.attitude_target
        if self.shaped is not Shaped.ATTITUDE:
            self.shaper.reset_attitude(m[MEASUREMENT.euler_rad],
                                       m[MEASUREMENT.euler_rate_rad_s])
            self.shaped = Shaped.ATTITUDE
        tilt_filter = (p["CMDF_OMEGA"], p["CMDF_ZETA"], p["CMDF_RATE_MAX"], p["CMDF_ACC_MAX"])
        dt = self.step_s / self.step_periods  # periods lost: filtered one by one
        for _ in range(self.step_periods):
            ref = self.shaper.step_attitude(target.euler_rad, self.limits, tilt_filter, dt,
                                            target.yaw_rate_rad_s)
        ref[REF_POS:REF_POS + 3] = m[MEASUREMENT.position_ned_m]
        if math.isfinite(target.thrust_fraction):
            return TaskOutput(ref, False, target.thrust_fraction * self.max_thrust_n)
        target.altitude_ref_ned_m -= target.climb_rate_mps * self.step_s
        ref[REF_POS + 2] = target.altitude_ref_ned_m
        ref[REF_VEL + 2] = -target.climb_rate_mps
        return TaskOutput(ref, False, math.nan)


@dataclass
class TaskEnv:
    """What a flight task may use: the shared state, the navigator, the paper's reference
    (None when not configured), a way to switch mode (a task handing over, as a mission
    ending in a return) and the vehicle's STATUSTEXT."""

    state: TaskState
    navigator: Navigator
    reference: Reference | None
    switch_to: Callable[[FlightMode], None]
    say: Callable[..., Any]


class BaseTask:
    """Defaults of a flight task: entering changes nothing, arming holds where the vehicle
    is, not landing."""

    def __init__(self, env: TaskEnv) -> None:
        self.env = env
        self.state = env.state

    def activate(self, previous: FlightMode, armed: bool) -> None:
        pass

    def on_arm(self) -> None:
        self.state.hold_here()

    @property
    def landing(self) -> bool:
        return False
