"""What makes the commander PX4 or ArduPilot Copter: the one place a flavour's arming and
mode rules, and the words it says them in, are decided.

PX4 (this vehicle's first flavour): boots in HOLD (AUTO.LOITER); a mode that ends with the
flight falls back to HOLD on disarm; a mode is entered only when its needs are met (the
mode table's entry checks, armed or not); arming where the mode table allows it; texts in
this vehicle's own words.

Copter (ArduCopter 4.5/4.6: mode.cpp ``Copter::set_mode``, mode.h ``allows_arming``,
AP_Arming_Copter.cpp, GCS_MAVLink_Copter.cpp): boots in STABILIZE and stays in its mode on
disarm; disarmed, any mode it flies may be selected (set_mode's ``ignore_checks``), armed,
the mode's needs apply; arming only in STABILIZE, ALT_HOLD, GUIDED, LOITER and POSHOLD
(AUTO only with AUTO_OPTIONS bit 0, off by default); a take-off only in GUIDED, armed and
on the ground; position and attitude targets obeyed in GUIDED only (ignored elsewhere);
GUIDED requests (go-to and altitude items, DO_REPOSITION, CONDITION_YAW, DO_SET_ROI*);
force-arm with param2 2989; DO_FLIGHTTERMINATION; a refused arm, take-off or mode change
answered MAV_RESULT_FAILED; "PreArm: ...", "Arm: ...", "Mode change to X failed: ..."
texts, "Arming motors" / "Disarming motors" (Copter SITL's), no text on a mode change (the
HEARTBEAT says it).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

from autopilot.commander.failsafe import Stream
from autopilot.commander.modes import EntryView, ModeRow
from autopilot.refusal import RefusedError
from contracts.modes import COPTER_MODE_NAMES, FlightMode, copter_mode_name

# Copter's ArduCopter modes that allow arming from a ground station (mode.h allows_arming)
# among those this vehicle flies.
COPTER_ARMABLE = frozenset({FlightMode.STABILIZED, FlightMode.ALTCTL, FlightMode.GUIDED,
                            FlightMode.HOLD, FlightMode.POSCTL})
FORCE_ARM_MAGIC = 2989  # COMPONENT_ARM_DISARM param2: arm without the checks (ArduPilot)


@dataclass(frozen=True)
class ArmingView:
    """What the arming checks read of the vehicle: a snapshot the commander takes."""

    navigation_problem: str | None  # why the estimate is not good enough, None if it is
    has_state: bool  # the simulator's state is here and its link up
    landed: bool
    force: bool  # Copter's 2989: the mode and ground checks skipped
    streaming: bool  # the mode's input stream is heard (False for a mode without one)


@dataclass(frozen=True)
class Personality:
    """One flavour's rules; texts are format strings (``{mode}``: the mode's name as the
    flavour writes it, ``{reason}``: this vehicle's reason)."""

    name: str
    boot_mode: FlightMode
    mode_name: Callable[[FlightMode], str]
    keeps_mode_on_disarm: bool  # disarming leaves the mode as it is
    any_mode_disarmed: bool  # disarmed, a mode is selected without its entry checks
    armable: frozenset[FlightMode] | None  # the modes arming is allowed in (None: table)
    arm_needs_manual: bool  # arming in a stick mode needs the sticks (Copter: RC)
    takeoff_mode: FlightMode | None  # a take-off flies in this mode only (None: TAKEOFF)
    takeoff_needs_ground: bool  # a take-off only from the ground
    setpoints_in_guided_only: bool  # targets outside a setpoint mode are ignored
    falls_back_disarmed: bool  # a lost input stream moves a disarmed vehicle to HOLD
    force_arm: bool  # COMPONENT_ARM_DISARM param2 2989 arms without the checks
    flight_termination: bool  # MAV_CMD_DO_FLIGHTTERMINATION is served
    # GUIDED requests: MISSION_ITEM(_INT) current=2/3 (a go-to / altitude change),
    # DO_REPOSITION as a GUIDED go-to, CONDITION_YAW and DO_SET_ROI* as commands
    guided_requests: bool
    refusals_fail: bool  # a refused arm, take-off or mode change: MAV_RESULT_FAILED
    armed_text: str
    disarmed_text: str  # a tool's disarm
    landed_disarmed_text: str  # the land detector's disarm after a landing
    terminated_text: str
    no_state_text: str
    navigation_text: str
    not_armable_text: str
    in_the_air_text: str
    no_sticks_text: str
    mode_failed_text: str
    mode_changed_text: str | None  # None: nothing said (the HEARTBEAT shows the mode)
    no_such_mode_text: str

    def mode_failed(self, mode: FlightMode, reason: str) -> str:
        return self.mode_failed_text.format(mode=self.mode_name(mode), reason=reason)

    def can_arm_in(self, mode: FlightMode, table_armable: bool) -> bool:
        return table_armable if self.armable is None else mode in self.armable

    def check_entry(self, mode: FlightMode, row: ModeRow, view: EntryView,
                    streaming: bool, navigator_check: Callable[[], None]) -> None:
        """Raise RefusedError, in the flavour's words, when ``mode`` cannot be entered now
        (``streaming``: its input stream is heard, or it has none; ``navigator_check``
        raises when the mission cannot start so, e.g. Copter's AUTO without a take-off)."""
        try:
            if not streaming:
                raise RefusedError(f"{mode.value} denied: no {row.stream.value}",
                                   temporary=True)
            if row.entry is not None:
                row.entry(view)
            navigator_check()
        except RefusedError as exc:
            raise RefusedError(self.mode_failed(mode, str(exc)), exc.temporary) from None

    def check_takeoff(self, mode: FlightMode, landed: bool) -> None:
        """Raise RefusedError when a take-off command is not for this mode or moment."""
        if self.takeoff_mode is not None and mode != self.takeoff_mode:
            raise RefusedError(f"take-off needs {self.mode_name(self.takeoff_mode)} mode")
        if self.takeoff_needs_ground and not landed:
            raise RefusedError("take-off denied: already flying")

    def check_arming(self, mode: FlightMode, row: ModeRow, v: ArmingView) -> None:
        """Raise RefusedError, in the flavour's words, when arming is not allowed now."""
        if v.navigation_problem is not None:
            raise RefusedError(self.navigation_text.format(reason=v.navigation_problem),
                               temporary=True)
        if not v.has_state:
            raise RefusedError(self.no_state_text, temporary=True)
        if not v.force and not self.can_arm_in(mode, row.armable):
            raise RefusedError(self.not_armable_text.format(mode=self.mode_name(mode)))
        if not v.force and not v.landed:
            raise RefusedError(self.in_the_air_text)
        if row.arm_needs_stream and not v.streaming:
            raise RefusedError("arming denied: no offboard setpoints", temporary=True)
        if self.arm_needs_manual and row.stream is Stream.MANUAL and not v.streaming:
            raise RefusedError(self.no_sticks_text, temporary=True)

    def unflown_mode(self, number: int, label: str) -> str:
        """Why a mode number this vehicle does not fly is refused (``label``: the number
        as the tool sent it)."""
        name = COPTER_MODE_NAMES.get(number) if self.name == "ardupilot" else None
        if name is None:
            return self.no_such_mode_text.format(number=label)
        return self.mode_failed_text.format(mode=name, reason="not available in this SITL")


PX4 = Personality(
    name="px4", boot_mode=FlightMode.HOLD, mode_name=lambda m: m.value,
    keeps_mode_on_disarm=False, any_mode_disarmed=False, armable=None,
    arm_needs_manual=False, takeoff_mode=None, takeoff_needs_ground=False,
    setpoints_in_guided_only=False, falls_back_disarmed=True, force_arm=False,
    flight_termination=False, guided_requests=False, refusals_fail=False,
    armed_text="armed", disarmed_text="disarmed", landed_disarmed_text="landed: disarmed",
    terminated_text="flight terminated: disarmed",
    no_state_text="arming denied: no state from the simulator",
    navigation_text="arming denied: {reason}", not_armable_text="arming denied in {mode} mode",
    in_the_air_text="arming denied: not on the ground",
    no_sticks_text="arming denied: no manual control input",
    mode_failed_text="{reason}", mode_changed_text="mode {mode}",
    no_such_mode_text="unknown mode {number}",
)

COPTER = Personality(
    name="ardupilot", boot_mode=FlightMode.STABILIZED, mode_name=copter_mode_name,
    keeps_mode_on_disarm=True, any_mode_disarmed=True, armable=COPTER_ARMABLE,
    arm_needs_manual=True, takeoff_mode=FlightMode.GUIDED, takeoff_needs_ground=True,
    setpoints_in_guided_only=True, falls_back_disarmed=False, force_arm=True,
    flight_termination=True, guided_requests=True, refusals_fail=True,
    armed_text="Arming motors", disarmed_text="Disarming motors",
    landed_disarmed_text="Disarming motors", terminated_text="Disarming motors",
    no_state_text="PreArm: Need Position Estimate", navigation_text="PreArm: AHRS: {reason}",
    not_armable_text="Arm: {mode} mode not armable",
    in_the_air_text="Arm: in the air (force with param2 2989)",
    no_sticks_text="PreArm: RC not found",
    mode_failed_text="Mode change to {mode} failed: {reason}", mode_changed_text=None,
    no_such_mode_text="No such mode {number}",
)

PERSONALITIES = {p.name: p for p in (PX4, COPTER)}
