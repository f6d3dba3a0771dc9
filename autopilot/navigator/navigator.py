"""The navigator: the stored mission, fence and rally lists, and the mission being flown.

It turns the mission runner's events into what ground tools see (the current item, items
reached, the mission's state) and tells the commander when a mission asks for a return
(pure: no I/O; announcements go through the ``say`` it is given).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from autopilot.flight_tasks.goal import Goal
from autopilot.navigator.home import Places
from autopilot.navigator.mission_runner import EventKind, MissionRunner, nav_command
from autopilot.navigator.mission_store import MAX_SPEED_MPS, MISSION, MissionStore
from autopilot.refusal import RefusedError
from contracts.frames import DEFAULT_HOME
from contracts.mavlink import mavlink
from contracts.modes import FlightMode


class Navigator:
    """The mission store and the runner flying (or pausing) its mission."""

    def __init__(self, say: Callable[..., None], copter_rules: bool = False) -> None:
        # ArduPilot Copter's mission rules (the ArduPilot flavour): a position item at
        # latitude and longitude 0 is flown where the vehicle is
        # (MissionRunner.zero_latlon_is_here), and AUTO on the ground, armed, needs a
        # take-off first (missing_takeoff).
        self.copter_rules = copter_rules
        self.store = MissionStore()  # mission, fence and rally lists, kept across modes
        self.runner: MissionRunner | None = None  # the mission being flown (or paused)
        self.complete = False
        self.reached: list[int] = []  # mission items reached, for MISSION_ITEM_REACHED
        self._current_shown = 0  # the current item as the runner last set it
        self._say = say
        self.places = Places.at(DEFAULT_HOME)  # the vehicle's origin and home, set with it

    @property
    def mission(self) -> tuple:
        return self.store.lists[MISSION]

    def select(self, first_seq: int) -> None:
        """MAV_CMD_MISSION_START's item: the next start flies from ``first_seq``."""
        items = self.mission
        if not items:
            raise RefusedError("mission denied: no mission uploaded")
        if not 0 <= first_seq < len(items):
            raise RefusedError(f"mission start: no item {first_seq} (the mission has "
                               f"{len(items)})")
        self.store.current = first_seq
        self.runner, self.complete = None, False

    def start(self, stopping_point: np.ndarray, heading_rad: float, landed: bool,
              parameters: dict[str, float]) -> bool:
        """Begin or resume the stored mission at its current item (a mission flown to its
        end begins again). True when it asks for a return at once."""
        items = self.mission
        if self.complete or self.store.current >= len(items) or self.runner is None or \
                self.runner.items is not items:  # from the start, fresh jump counts and speed
            if self.complete or self.store.current >= len(items):
                self.store.current = 0
            self.runner = MissionRunner(items, parameters, self.places,
                                        zero_latlon_is_here=self.copter_rules)
        self.complete = False  # (resuming keeps the jump counts and the speed)
        self.runner.start(self.store.current, stopping_point, heading_rad, landed,
                          parameters["MIS_TAKEOFF_ALT"])
        return self._take_events()

    def check_mode_entry(self, mode: FlightMode, armed: bool, landed: bool) -> None:
        """Copter refuses AUTO (MISSION) when armed on the ground with a mission whose
        next position item is not a take-off (ModeAuto::init: it would drag or flip the
        vehicle): RefusedError. Only under copter_rules: PX4 climbs first instead."""
        if mode != FlightMode.MISSION or not (self.copter_rules and armed and landed):
            return
        if nav_command(self.mission, self.store.current) != mavlink.MAV_CMD_NAV_TAKEOFF:
            raise RefusedError("Auto: Missing Takeoff Cmd")

    @property
    def uploaded_anew(self) -> bool:
        """A mission (or none) was uploaded since the runner began its own."""
        return self.runner.items is not self.mission

    @property
    def current_moved(self) -> bool:
        """A tool set the current item since the runner last did."""
        return self.store.current != self._current_shown

    def step(self, sim_t_s: float, here_ned_m: np.ndarray, reference_ned_m: np.ndarray,
             parameters: dict[str, float],
             reference_velocity_ned_mps: np.ndarray | None = None) -> Goal | None:
        """This period's goal; None when the mission asks for a return."""
        self.runner.parameters = parameters  # changed in flight: they apply at once
        self.runner.places = self.places  # and home, moved by a tool (DO_SET_HOME)
        goal = self.runner.step(sim_t_s, here_ned_m, reference_ned_m,
                                reference_velocity_ned_mps)
        return None if self._take_events() else goal

    def _take_events(self) -> bool:
        runner = self.runner
        items = runner.items
        self.store.current = runner.seq if runner.seq < len(items) else len(items) - 1
        self._current_shown = self.store.current
        wants_return = False
        while runner.events:
            event = runner.events.pop(0)
            if event.kind is EventKind.REACHED:
                self.reached.append(event.seq)
            elif event.kind is EventKind.HOME:  # the vehicle's home, from now on
                self.places = runner.places
            elif event.kind is EventKind.FINISHED:
                self.complete = True
                self._say(event.text)
            else:  # the mission ends in a return (always its last event)
                self.complete = True
                self._say("mission: returning to launch")
                wants_return = True
        return wants_return

    def flight_ended(self) -> None:
        """Disarmed: a mission flown to its landing or its end begins again next time."""
        runner = self.runner
        if runner is not None and (runner.landing or runner.finished):
            self.runner, self.complete = None, False
            self.store.current = 0

    def change_speed(self, speed_mps: float) -> bool:
        """MAV_CMD_DO_CHANGE_SPEED: the mission's speed; False for -1 (no change)."""
        if speed_mps == -1.0:
            return False
        if not (math.isfinite(speed_mps) and 0.0 < speed_mps <= MAX_SPEED_MPS):
            raise RefusedError(f"speed {speed_mps:g} m/s is outside (0, {MAX_SPEED_MPS:g}]")
        if self.runner is not None:
            self.runner.speed_mps = speed_mps
        return True

    def state(self, active: bool) -> str:
        """none, not started, active, paused or complete (MISSION_CURRENT's states)."""
        items = self.mission
        if not items:
            return "none"
        if self.complete:
            return "complete"
        if self.runner is None or self.runner.items is not items:
            return "not started"
        return "active" if active else "paused"
