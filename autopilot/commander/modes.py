"""The mode table: one row per flight mode, read by the commander.

A row says what the mode allows (arming in it, streamed setpoints applied at once), what
entering it needs (checked before anything changes), which flight task produces its
reference (the task's ``activate`` is what entering does, its ``landing`` how it lands),
which input stream it flies on (entering and arming may need it; its loss is the
stream's failsafe, autopilot/commander/failsafe.py), whether disarming ends it, whether
the geofence is checked and the total tilt limited in it. Adding a mode is a row here,
a task in autopilot/flight_tasks/ and its numbers in contracts/modes.py.

Entry checks read an :class:`EntryView` (plain values the commander fills in, as the
flight tasks read ``TaskEnv``); a mode entered by a command instead calls it on the
:class:`ModeCommands` the commander offers.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import partial
from typing import Protocol

from autopilot.commander.failsafe import Stream
from autopilot.flight_tasks.follow import FollowTargetTask
from autopilot.flight_tasks.hold import HoldTask
from autopilot.flight_tasks.land import LandTask
from autopilot.flight_tasks.manual import AttitudeControlTask, PositionControlTask
from autopilot.flight_tasks.mission import MissionTask
from autopilot.flight_tasks.offboard import OffboardTask
from autopilot.flight_tasks.orbit import OrbitTask
from autopilot.flight_tasks.reference import ReferenceTask
from autopilot.flight_tasks.rtl import ReturnTask
from autopilot.flight_tasks.takeoff import TakeoffTask
from autopilot.flight_tasks.task import FlightTask, TaskEnv
from autopilot.refusal import RefusedError
from contracts.modes import FlightMode


@dataclass(frozen=True)
class EntryView:
    """What a mode's entry check reads of the vehicle: a snapshot the commander takes."""

    armed: bool
    landed: bool
    has_reference: bool  # a reference generator is configured (REFERENCE mode)
    has_mission: bool  # a mission is uploaded (MISSION mode)


class ModeCommands(Protocol):
    """The commands a mode may be entered by instead of a plain switch."""

    def takeoff(self, relative_altitude_m: float | None) -> None:
        """Climb to ``relative_altitude_m`` (None: MIS_TAKEOFF_ALT) in TAKEOFF."""
        ...


@dataclass(frozen=True)
class ModeRow:
    task: Callable[[TaskEnv], FlightTask]  # makes the task that flies the mode
    armable: bool = False  # arming allowed in the mode
    follows_setpoints: bool = False  # a streamed setpoint applies as it arrives
    stream: Stream | None = None  # the input it flies on: needed to enter, loss: failsafe
    arm_needs_stream: bool = False  # arming needs the stream too
    entry: Callable[[EntryView], None] | None = None  # raises RefusedError: not now
    command: Callable[[ModeCommands], None] | None = None  # entered by this command instead
    ends_with_flight: bool = False  # disarming leaves it for the idle mode
    geofence: bool = True  # the fence is checked in flight
    tilt_limited: bool = True  # the total tilt is limited (MPC_TILTMAX_AIR)


def _needs_armed(what: str) -> Callable[[EntryView], None]:
    def check(v: EntryView) -> None:
        if not v.armed:
            raise RefusedError(f"{what} denied: disarmed", temporary=True)
    return check


def _needs_air(what: str) -> Callable[[EntryView], None]:
    def check(v: EntryView) -> None:
        if not v.armed or v.landed:
            raise RefusedError(f"{what} denied: not in the air", temporary=True)
    return check


def _needs_reference(v: EntryView) -> None:
    if not v.has_reference:
        raise RefusedError("no reference generator configured")
    if not v.armed or v.landed:
        raise RefusedError("the reference needs an armed vehicle in the air", temporary=True)


def _needs_mission(v: EntryView) -> None:
    if not v.has_mission:
        raise RefusedError("mission denied: no mission uploaded")


def _take_off(c: ModeCommands) -> None:
    c.takeoff(None)


MODES: dict[FlightMode, ModeRow] = {
    FlightMode.HOLD: ModeRow(HoldTask, armable=True),
    FlightMode.TAKEOFF: ModeRow(TakeoffTask, armable=True, command=_take_off,
                                ends_with_flight=True),
    FlightMode.LAND: ModeRow(LandTask, entry=_needs_armed("landing"), ends_with_flight=True),
    FlightMode.OFFBOARD: ModeRow(partial(OffboardTask, streams=True), armable=True,
                                 follows_setpoints=True, stream=Stream.SETPOINTS,
                                 arm_needs_stream=True),
    FlightMode.GUIDED: ModeRow(partial(OffboardTask, streams=False), armable=True,
                               follows_setpoints=True),
    FlightMode.REFERENCE: ModeRow(ReferenceTask, entry=_needs_reference,
                                  ends_with_flight=True, geofence=False, tilt_limited=False),
    FlightMode.MISSION: ModeRow(MissionTask, armable=True, entry=_needs_mission,
                                ends_with_flight=True),
    FlightMode.RTL: ModeRow(ReturnTask, entry=_needs_air("return"), ends_with_flight=True),
    FlightMode.ORBIT: ModeRow(OrbitTask, entry=_needs_air("orbit"), ends_with_flight=True),
    FlightMode.FOLLOW_TARGET: ModeRow(FollowTargetTask, entry=_needs_air("follow target"),
                                      ends_with_flight=True),
    # Copter's BRAKE (no PX4 number): HOLD's stop and hold, in the air only, never armed in.
    FlightMode.BRAKE: ModeRow(HoldTask, entry=_needs_air("brake")),
    FlightMode.POSCTL: ModeRow(PositionControlTask, armable=True, stream=Stream.MANUAL),
    FlightMode.ALTCTL: ModeRow(partial(AttitudeControlTask, thrust_stick=False),
                               armable=True, stream=Stream.MANUAL),
    FlightMode.STABILIZED: ModeRow(partial(AttitudeControlTask, thrust_stick=True),
                                   armable=True, stream=Stream.MANUAL),
}
