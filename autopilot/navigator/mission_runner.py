"""The mission runner: what the vehicle flies in AUTO.MISSION (pure: no I/O).

As PX4's navigator, it does not fly anything itself: each control period it hands the
vehicle a *goal*, a position setpoint with a speed and a vertical manner (take-off
climb, landing descent), and the vehicle flies it through the same setpoint shaping as a
tool's setpoints (autopilot/flight_tasks/shaping.py). What it reports (an item reached, the current
item, a return asked for, the mission finished) comes back as events.

Missions follow PX4's rules (docs/missions.md): a waypoint is *reached* when the vehicle
is within its acceptance radius (NAV_ACC_RAD when the item gives none) and within
NAV_MC_ALT_RAD of its altitude. A corner is flown as PX4 flies it: rounded inside the
acceptance radius at a reduced speed (:func:`corner_speed_mps`). The next leg starts
once the shaped reference is inside the radius and has slowed to the corner's speed; the
reference then turns towards the next waypoint at its acceleration limit. A waypoint
with a hold time, the last one, and a reversal are stopped at (AT_WAYPOINT_M), and a
hold time runs from then. Headings face the next waypoint (PX4's MPC_YAW_MODE 0) unless
the item names one.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from autopilot.flight_tasks.goal import LAND_DOWN_M, Goal, Vertical
from autopilot.flight_tasks.shaping import Setpoint
from autopilot.navigator.home import Places
from autopilot.navigator.mission_store import (
    ARDUPILOT_DO_COMMANDS,
    DO_COMMANDS,
    PAYLOAD_COMMANDS,
    MissionItem,
    is_roi_none,
)
from contracts.frames import Home
from contracts.mavlink import GLOBAL_FRAMES, mavlink

M = mavlink
# A leg that turns starts once the shaped reference has come to within this distance of
# the waypoint (nearly at rest, its braking over): the turn then stays within a few
# centimetres of the path. A hold time runs from the same moment. Legs that go straight
# on start as soon as the reference is within the acceptance radius.
AT_WAYPOINT_M = 0.05
STRAIGHT_ON_RAD = math.radians(10.0)  # legs this close to straight do not slow down
# The share of MPC_ACC_HOR a corner's arc may take across the path: the rest is left to
# the reference's braking along it, so the rounded path stays inside the radius.
CORNER_ACCEL_SHARE = 0.5
FACE_TARGET_M = 2.0  # legs shorter than this keep the heading (no spinning on the spot)
# Items flown to a position and left (after a hold) for the next.
WAYPOINT_COMMANDS = (M.MAV_CMD_NAV_WAYPOINT, M.MAV_CMD_NAV_LOITER_TIME,
                     M.MAV_CMD_NAV_LOITER_UNLIM)
# Items whose param4 is a heading [deg] (NAV_LOITER_TIME's is a cross-track flag).
YAW_COMMANDS = (M.MAV_CMD_NAV_WAYPOINT, M.MAV_CMD_NAV_LOITER_UNLIM, M.MAV_CMD_NAV_TAKEOFF,
                M.MAV_CMD_NAV_LAND)
MAX_DO_ITEMS_PER_STEP = 64  # a DO_JUMP loop without a position in it cannot stall a step


class Phase(enum.Enum):
    """Where the runner is in the current item."""

    START = "start"  # begin the current item at the next step
    CLIMB = "climb"  # on the ground at the start: straight up to the first altitude
    TAKEOFF = "takeoff"  # a NAV_TAKEOFF item
    FLY = "fly"  # to a positioned item
    WAIT = "wait"  # a NAV_DELAY
    LAND = "land"  # descending on a NAV_LAND item
    DONE = "done"  # finished, or handed over to a return


class EventKind(enum.Enum):
    REACHED = "reached"  # an item reached (MISSION_ITEM_REACHED)
    RETURN = "return"  # the mission asks for a return to launch
    HOME = "home"  # a DO_SET_HOME item moved home (MissionRunner.places)
    FINISHED = "finished"  # the mission ended (the text says how)


class Event(NamedTuple):
    """What the runner reports to the navigator."""

    kind: EventKind
    seq: int = -1
    text: str = ""


def item_position_ned(item: MissionItem, here_ned_m: np.ndarray, places: Places,
                      zero_latlon_is_here: bool = False) -> np.ndarray:
    """A positioned item's target in local NED (around the origin, relative altitudes
    above home: Places). A landing item at latitude
    and longitude 0 (or x, y NaN in LOCAL_NED) lands where the vehicle is; with
    ``zero_latlon_is_here`` (ArduPilot Copter) so does every position item at 0, 0, at
    its own altitude."""
    if item.is_global:
        here_latlon = item.x == 0 and item.y == 0
        out = places.ned_from_global(item.frame, item.x * 1e-7, item.y * 1e-7, item.z)
    else:
        here_latlon = not (math.isfinite(item.x) and math.isfinite(item.y))
        out = np.array([item.x, item.y, item.z], dtype=float)
    # A take-off climbs straight up where the vehicle is, as PX4's does.
    if item.command == M.MAV_CMD_NAV_TAKEOFF or (here_latlon and (
            zero_latlon_is_here or item.command == M.MAV_CMD_NAV_LAND)):
        out[0:2] = here_ned_m[0:2]
    return out


def nav_command(items: tuple[MissionItem, ...], seq: int) -> int | None:
    """The command of the first item from ``seq`` on that is not a do item (None: none)."""
    for item in items[seq:]:
        if item.command not in DO_COMMANDS and item.command not in ARDUPILOT_DO_COMMANDS:
            return item.command
    return None


def heading_to(start_ned_m: np.ndarray, target_ned_m: np.ndarray) -> float:
    """The heading from ``start`` to ``target`` [rad], NaN when they are close."""
    d = target_ned_m[0:2] - start_ned_m[0:2]
    if math.hypot(d[0], d[1]) < FACE_TARGET_M:
        return math.nan
    return math.atan2(d[1], d[0])


def corner_speed_mps(turn_rad: float, acceptance_m: float, acc_hor_mps2: float,
                     cruise_mps: float) -> float:
    """The speed a corner is passed at: the arc tangent to both legs at ``acceptance_m``
    from the waypoint has the radius acceptance / tan(turn / 2), and flown at a lateral
    acceleration of CORNER_ACCEL_SHARE * MPC_ACC_HOR it allows sqrt(a r); at most the
    cruise speed, nothing for a reversal."""
    if turn_rad < STRAIGHT_ON_RAD:
        return cruise_mps
    if turn_rad >= math.pi - 1e-6:
        return 0.0
    radius_m = acceptance_m / math.tan(0.5 * turn_rad)
    return min(cruise_mps, math.sqrt(CORNER_ACCEL_SHARE * acc_hor_mps2 * radius_m))


def turn_angle(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> float:
    """The angle the path turns through at ``b`` going a -> b -> c [rad]."""
    u, w = b - a, c - b
    nu, nw = float(np.linalg.norm(u)), float(np.linalg.norm(w))
    if nu < 1e-6 or nw < 1e-6:
        return math.pi
    return math.acos(max(-1.0, min(1.0, float(np.dot(u, w)) / (nu * nw))))


@dataclass
class MissionRunner:
    """Flies a stored mission from its current item. ``step`` once per control period."""

    items: tuple[MissionItem, ...]
    parameters: dict[str, float]
    places: Places  # the origin items' latitudes and longitudes are taken around, home
    zero_latlon_is_here: bool = False  # Copter: a position item at 0, 0 is "here"
    seq: int = 0
    speed_mps: float = math.nan  # DO_CHANGE_SPEED; NaN: MPC_XY_CRUISE
    events: list[Event] = field(default_factory=list)  # for the navigator to act on
    finished: bool = False
    _phase: Phase = Phase.START
    _target: np.ndarray = field(default_factory=lambda: np.zeros(3))
    _leg_start: np.ndarray = field(default_factory=lambda: np.zeros(3))
    _yaw_rad: float = 0.0
    _reached_s: float | None = None
    _hold_from_s: float | None = None
    _wait_until_s: float = 0.0
    _jumps_left: dict[int, int] = field(default_factory=dict)
    _roi_ned_m: np.ndarray | None = None  # the region of interest the nose points at

    def start(self, seq: int, position_ned_m: np.ndarray, yaw_rad: float, landed: bool,
              take_off_alt_m: float) -> None:
        """Begin (or resume) at item ``seq`` from ``position_ned_m``. On the ground a
        mission that does not begin with a take-off climbs first, straight up, to the
        first waypoint's altitude (at least ``take_off_alt_m``), as PX4 does."""
        self.seq, self.finished = seq, False
        self._yaw_rad = yaw_rad
        self._leg_start = np.array(position_ned_m, dtype=float)
        self._phase = Phase.START
        if landed and self._nav_command(seq) != M.MAV_CMD_NAV_TAKEOFF:
            first = self._first_position(seq, position_ned_m)
            altitude = max(take_off_alt_m, -first[2]) if first is not None else take_off_alt_m
            self._target = np.array([position_ned_m[0], position_ned_m[1], -altitude])
            self._phase = Phase.CLIMB
        else:
            self._begin_item(position_ned_m, 0.0)

    # -- the items ---------------------------------------------------------------------
    def _nav_command(self, seq: int) -> int | None:
        return nav_command(self.items, seq)

    def _first_position(self, seq: int, here: np.ndarray) -> np.ndarray | None:
        for item in self.items[seq:]:
            if item.command in (*WAYPOINT_COMMANDS, M.MAV_CMD_NAV_TAKEOFF):
                return self._position(item, here)
        return None

    def _position(self, item: MissionItem, here: np.ndarray) -> np.ndarray:
        return item_position_ned(item, here, self.places, self.zero_latlon_is_here)

    def _begin_item(self, here: np.ndarray, t_s: float) -> None:
        """Set up the current item, carrying out DO items on the way to the next one
        with a position or a wait."""
        for _ in range(MAX_DO_ITEMS_PER_STEP):
            if self.seq >= len(self.items):
                self._finish("mission finished")
                return
            item = self.items[self.seq]
            command = item.command
            if command == M.MAV_CMD_DO_CHANGE_SPEED:
                if item.params[1] > 0:
                    self.speed_mps = float(item.params[1])
                self.seq += 1
                continue
            if command == M.MAV_CMD_DO_SET_HOME and self._phase is Phase.START:
                self._set_home(item, here)  # before any position item: runs here
            if command in PAYLOAD_COMMANDS or command in ARDUPILOT_DO_COMMANDS:
                self.seq += 1  # no payload to drive; yaw and ROI items ran with the last
                continue       # position item (_run_conditionals)
            if command == M.MAV_CMD_DO_JUMP:
                left = self._jumps_left.setdefault(self.seq, int(item.params[1]))
                if left != 0:
                    self._jumps_left[self.seq] = left - 1 if left > 0 else -1
                    self.seq = int(item.params[0])
                else:
                    self.seq += 1
                continue
            break
        else:
            self._finish("mission stopped: DO_JUMP loop without a position")
            return
        self._reached_s = self._hold_from_s = None
        self._leg_start = self._target.copy() if self._phase not in (Phase.START, Phase.CLIMB) \
            else np.array(here, dtype=float)
        if command == M.MAV_CMD_NAV_RETURN_TO_LAUNCH:  # the mission ends in a return
            self.events.append(Event(EventKind.RETURN))
            self.finished = True
            self._phase = Phase.DONE
            return
        if command == M.MAV_CMD_NAV_DELAY:  # wait where the last item left the vehicle
            if self._phase is Phase.START:
                self._target = np.array(here, dtype=float)
            self._phase = Phase.WAIT
            self._wait_until_s = t_s + float(item.params[0])
            return
        target = self._position(item, self._leg_start)
        if command == M.MAV_CMD_NAV_LAND:
            target[2] = self._leg_start[2]  # fly there at this altitude, then descend
        self._target = target
        yaw = item.params[3] if command in YAW_COMMANDS else math.nan
        face = heading_to(self._leg_start, target)
        self._yaw_rad = math.radians(yaw) if math.isfinite(yaw) else (
            face if math.isfinite(face) else self._yaw_rad)
        self._phase = Phase.TAKEOFF if command == M.MAV_CMD_NAV_TAKEOFF else Phase.FLY
        self._run_conditionals(here)

    def _run_conditionals(self, here: np.ndarray) -> None:
        """ArduPilot Copter's yaw and ROI items (ARDUPILOT_DO_COMMANDS) that follow the
        item just begun run at once, during its leg, as AP_Mission starts the do and
        condition commands after a navigation command: CONDITION_YAW turns to a heading
        (absolute, or relative to the present one, clockwise or not) held until the
        next position item; a region of interest keeps the nose on it from now on (each
        leg too) until a DO_SET_ROI_NONE or an ROI at 0, 0."""
        for item in self.items[self.seq + 1:]:
            command = item.command
            if command not in DO_COMMANDS and command not in ARDUPILOT_DO_COMMANDS:
                return
            if command == M.MAV_CMD_CONDITION_YAW:
                angle = math.radians(item.params[0])
                self._yaw_rad = self._yaw_rad + (-angle if item.params[2] < 0 else angle) \
                    if item.params[3] == 1.0 else angle
                self._roi_ned_m = None  # Copter: a fixed heading replaces the ROI
            elif command == M.MAV_CMD_DO_SET_HOME:
                self._set_home(item, here)
            elif is_roi_none(item):
                self._roi_ned_m = None
            elif command in ARDUPILOT_DO_COMMANDS:  # an ROI at a location
                self._roi_ned_m = item_position_ned(item, here, self.places)

    def _set_home(self, item: MissionItem, here: np.ndarray) -> None:
        """DO_SET_HOME as Copter's mission runs it (do_set_home): param1 1 or latitude
        and longitude 0, home where the vehicle is; else at the item's location (a
        relative altitude above the present home). A place that is not a home is passed
        over, as Copter passes over a failed set_home."""
        origin = self.places.origin
        if item.params[0] == 1.0 or (item.x == 0 and item.y == 0):
            lat, lon, alt = origin.geodetic_from_ned(*here)
        else:
            lat, lon, alt = item.x * 1e-7, item.y * 1e-7, float(item.z)
            if GLOBAL_FRAMES[item.frame]:
                alt += self.places.home.alt_amsl_m
        try:
            home = Home.checked(lat, lon, alt)
        except ValueError:
            return
        self.places = self.places.moved_to(home)
        self.events.append(Event(EventKind.HOME, item.seq))

    def _heading(self, position_ned_m: np.ndarray) -> float:
        """The heading to fly: facing the region of interest when there is one (and it is
        not close by), else the item's."""
        if self._roi_ned_m is not None:
            face = heading_to(position_ned_m, self._roi_ned_m)
            if math.isfinite(face):
                self._yaw_rad = face
        return self._yaw_rad

    def _finish(self, text: str) -> None:
        if not self.finished:
            self.events.append(Event(EventKind.FINISHED, text=text))
        self.finished = True
        self._phase = Phase.DONE

    def _acceptance(self, item: MissionItem) -> tuple[float, float]:
        """(horizontal, vertical) acceptance [m]."""
        p = self.parameters
        radius = item.params[1] if item.command == M.MAV_CMD_NAV_WAYPOINT else math.nan
        if not (math.isfinite(radius) and radius > 0):
            radius = p["NAV_ACC_RAD"]
        return radius, p["NAV_MC_ALT_RAD"]

    def _hold_s(self, item: MissionItem) -> float:
        if item.command == M.MAV_CMD_NAV_LOITER_UNLIM:
            return math.inf  # hold there until the mission is left or restarted
        if item.command in (M.MAV_CMD_NAV_WAYPOINT, M.MAV_CMD_NAV_LOITER_TIME):
            return float(item.params[0]) if math.isfinite(item.params[0]) else 0.0
        return 0.0

    def _corner_speed(self, radius_m: float) -> float:
        """The speed the current waypoint may be left at for the next leg: 0 unless a
        waypoint follows (the path stops at the last one, and before a landing)."""
        following = self.seq + 1
        if following < len(self.items) and \
                self.items[following].command in WAYPOINT_COMMANDS:
            after = self._position(self.items[following], self._target)
            return corner_speed_mps(turn_angle(self._leg_start, self._target, after),
                                    radius_m, self.parameters["MPC_ACC_HOR"], self._speed())
        return 0.0

    # -- the step ----------------------------------------------------------------------
    def step(self, t_s: float, position_ned_m: np.ndarray, reference_ned_m: np.ndarray,
             reference_velocity_ned_mps: np.ndarray | None = None) -> Goal:
        """This period's goal, from the vehicle's position and the shaped reference's
        position and velocity (None: at rest)."""
        if self._phase is Phase.CLIMB:
            goal = Goal(Setpoint.hold(self._target, self._yaw_rad), math.nan, Vertical.TAKEOFF)
            if abs(position_ned_m[2] - self._target[2]) <= self.parameters["NAV_MC_ALT_RAD"]:
                self._begin_item(position_ned_m, t_s)
            return goal
        if self._phase is Phase.START:
            self._begin_item(position_ned_m, t_s)
        if self._phase is Phase.DONE:
            return Goal(Setpoint.hold(self._target, self._yaw_rad))
        if self._phase is Phase.LAND:
            return Goal(Setpoint.hold((*self._target[0:2], LAND_DOWN_M), self._yaw_rad),
                        math.nan, Vertical.LAND)
        if self._phase is Phase.WAIT:
            if t_s >= self._wait_until_s:
                self.events.append(Event(EventKind.REACHED, self.seq))
                self._next(position_ned_m, t_s)
            return Goal(Setpoint.hold(self._target, self._yaw_rad), self._speed())
        item = self.items[self.seq]
        radius, vertical = self._acceptance(item)
        error = self._target - position_ned_m
        if self._reached_s is None and math.hypot(error[0], error[1]) <= radius and \
                abs(error[2]) <= vertical:
            self._reached_s = t_s
            if item.command != M.MAV_CMD_NAV_LAND:
                self.events.append(Event(EventKind.REACHED, self.seq))
        if self._reached_s is not None:
            away = float(np.linalg.norm(reference_ned_m - self._target))
            if item.command == M.MAV_CMD_NAV_LAND:
                if away <= AT_WAYPOINT_M:
                    self._phase = Phase.LAND
                    self.events.append(Event(EventKind.REACHED, self.seq))
            elif self._hold_s(item) > 0.0:
                if self._hold_from_s is None and away <= AT_WAYPOINT_M:
                    self._hold_from_s = t_s
                if self._hold_from_s is not None and \
                        t_s - self._hold_from_s >= self._hold_s(item):
                    self._next(position_ned_m, t_s)
            elif away <= AT_WAYPOINT_M or (away <= radius and self._slowed_for_corner(
                    reference_velocity_ned_mps, radius)):
                self._next(position_ned_m, t_s)
        return Goal(Setpoint.hold(self._target, self._heading(position_ned_m)), self._speed(),
                    Vertical.TAKEOFF if self._phase is Phase.TAKEOFF else Vertical.CRUISE)

    def _slowed_for_corner(self, velocity_ned_mps: np.ndarray | None,
                           radius_m: float) -> bool:
        corner = self._corner_speed(radius_m)
        if corner <= 0.0:
            return False
        speed = 0.0 if velocity_ned_mps is None else float(np.linalg.norm(velocity_ned_mps))
        return speed <= corner

    def _next(self, here: np.ndarray, t_s: float) -> None:
        self.seq += 1
        self._begin_item(here, t_s)

    def _speed(self) -> float:
        return self.speed_mps if math.isfinite(self.speed_mps) else \
            self.parameters["MPC_XY_CRUISE"]

    @property
    def landing(self) -> bool:
        return self._phase is Phase.LAND
