"""The commands that say where an automatic mode flies: start the mission (PX4's
AUTO.MISSION), go to a position and hold there (AUTO.LOITER), change the speed.

They act on the navigator and on the tasks that fly HOLD and MISSION; what they need of
the rest of the vehicle (arming, mode, switching mode) they read through
:class:`AutoVehicle`, which the commander provides.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from autopilot.flight_tasks.hold import HoldTask
from autopilot.flight_tasks.mission import MissionTask
from autopilot.flight_tasks.offboard import OffboardTask
from autopilot.flight_tasks.shaping import Setpoint
from autopilot.flight_tasks.task import TaskState
from autopilot.navigator.geofence import breach, zones_from_items
from autopilot.navigator.mission_store import FENCE
from autopilot.navigator.navigator import Navigator
from autopilot.refusal import RefusedError
from contracts.frames import wrap_pi
from contracts.modes import FlightMode


class AutoVehicle(Protocol):
    """What the automatic modes' commands read of the vehicle and ask of it."""

    armed: bool
    mode: FlightMode

    @property
    def landed(self) -> bool: ...

    def set_mode(self, mode: FlightMode, link_t_s: float) -> None:
        """Enter ``mode`` as a tool asks for it (its needs checked first)."""
        ...


@dataclass(eq=False)
class AutoCommands:
    """MAV_CMD_MISSION_START, MAV_CMD_DO_REPOSITION and MAV_CMD_DO_CHANGE_SPEED; Copter's
    GUIDED go-to and altitude change (MISSION_ITEM current=2 / 3)."""

    vehicle: AutoVehicle
    navigator: Navigator
    hold: HoldTask
    mission: MissionTask
    state: TaskState
    say: Callable[[str], None]
    guided: OffboardTask | None = None  # GUIDED's task (a region of interest)

    def start_mission(self, first_seq: int, link_t_s: float) -> None:
        """MAV_CMD_MISSION_START: fly the mission from item ``first_seq``."""
        self.navigator.select(first_seq)
        if self.vehicle.mode == FlightMode.MISSION:
            self.mission.restart()
        else:
            self.vehicle.set_mode(FlightMode.MISSION, link_t_s)

    def reposition(self, target_ned_m: np.ndarray, yaw_rad: float, speed_mps: float) -> None:
        """MAV_CMD_DO_REPOSITION: fly to a position (NaN: keep that coordinate) and hold
        there, in HOLD (PX4's AUTO.LOITER)."""
        v = self.vehicle
        if not v.armed or v.landed:
            raise RefusedError("go-to denied: not in the air", temporary=True)
        if any(math.isinf(x) for x in (*target_ned_m, yaw_rad, speed_mps)):
            raise RefusedError("go-to values must be finite or NaN")
        if math.isfinite(speed_mps) and \
                not 0 < speed_mps <= self.state.parameters["MPC_XY_VEL_MAX"]:
            speed_mps = math.nan  # -1 (the default speed) or beyond the limit
        self.hold.reposition(target_ned_m, yaw_rad, speed_mps, v.mode is FlightMode.HOLD)

    def change_speed(self, speed_mps: float) -> None:
        """MAV_CMD_DO_CHANGE_SPEED in flight: the mission's speed and a go-to's (-1: no
        change)."""
        if not self.navigator.change_speed(speed_mps):
            return
        if self.vehicle.mode == FlightMode.HOLD:
            self.hold.speed_mps = speed_mps
        self.say(f"speed {speed_mps:.1f} m/s")

    def guided_go_to(self, target_ned_m: np.ndarray) -> None:
        """Copter's GUIDED go-to (DroneKit's simple_goto): fly to ``target_ned_m`` (all
        three given) and hold there, in GUIDED, in the air only; a target beyond the fence
        or 1 km from home is refused (Copter's set_destination refuses one outside the
        fence), nothing changed."""
        self._guided_in_the_air("go-to")
        self._fly_to(self.checked_go_to(target_ned_m))
        self.say(f"going to {target_ned_m[0]:.1f} N {target_ned_m[1]:.1f} E "
                 f"{-target_ned_m[2]:.1f} m up")

    def checked_go_to(self, target_ned_m: np.ndarray) -> np.ndarray:
        """A go-to target as given, after the checks that do not depend on the mode."""
        if not np.all(np.isfinite(target_ned_m)):
            raise RefusedError("go-to position must be finite")
        if np.any(np.abs(target_ned_m) > 1000.0):
            raise RefusedError("go-to position is more than 1 km from home")
        p = self.state.parameters
        places = self.navigator.places
        outside = breach(target_ned_m, zones_from_items(self.navigator.store.lists[FENCE],
                                                        places.origin),
                         p["GF_MAX_HOR_DIST"], p["GF_MAX_VER_DIST"], places.home_ned_m)
        if outside is not None:
            raise RefusedError(f"go-to denied: the target is {outside}")
        return np.array(target_ned_m, dtype=float)

    def guided_reposition(self, target_ned_m: np.ndarray, change_mode: bool,
                          link_t_s: float) -> None:
        """DO_REPOSITION in Copter's flavour: a GUIDED go-to (NaN keeps that coordinate of
        the current target); outside GUIDED only with the change-mode flag, which enters
        GUIDED first (checked before anything changes)."""
        v = self.vehicle
        if v.mode is not FlightMode.GUIDED and not change_mode:
            raise RefusedError("go-to needs GUIDED mode (or DO_REPOSITION's change-mode "
                               "flag)")
        if not v.armed or v.landed:
            raise RefusedError("go-to denied: not in the air", temporary=True)
        held = self.state.setpoint.position_ned_m
        here = held if v.mode is FlightMode.GUIDED and np.all(np.isfinite(held)) \
            else self.state.stopping_point()
        target = self.checked_go_to(np.where(np.isfinite(target_ned_m), target_ned_m, here))
        if v.mode is not FlightMode.GUIDED:
            v.set_mode(FlightMode.GUIDED, link_t_s)
        self.guided_go_to(target)

    def guided_altitude(self, relative_altitude_m: float) -> None:
        """MISSION_ITEM current=3 in GUIDED: the target's altitude above home changes, its
        horizontal position stays (Copter acknowledges and leaves it to a to-do)."""
        self._guided_in_the_air("altitude change")
        if not math.isfinite(relative_altitude_m) or not 0.5 <= relative_altitude_m <= 1000.0:
            raise RefusedError(f"altitude {relative_altitude_m:g} m is outside [0.5, 1000] m")
        target = self.state.setpoint.position_ned_m.copy()
        if not np.all(np.isfinite(target)):
            target = self.state.stopping_point()
        target[2] = -self.navigator.places.local_altitude_m(relative_altitude_m)
        p = self.state.parameters
        if p["GF_MAX_VER_DIST"] > 0 and relative_altitude_m > p["GF_MAX_VER_DIST"]:
            raise RefusedError(f"altitude change denied: {relative_altitude_m:g} m is above "
                               f"the fence's {p['GF_MAX_VER_DIST']:g} m")
        self._fly_to(target)
        self.say(f"changing altitude to {relative_altitude_m:.1f} m")

    def guided_yaw(self, angle_deg: float, direction: float, relative: bool) -> None:
        """MAV_CMD_CONDITION_YAW in GUIDED (Copter's): face ``angle_deg`` (0-360, clockwise
        from north), or turn by it (``relative``: clockwise, counter-clockwise when
        ``direction`` is -1); the turn rate is the vehicle's own. It ends a region of
        interest."""
        if not (math.isfinite(angle_deg) and 0.0 <= angle_deg <= 360.0):
            raise RefusedError(f"yaw angle {angle_deg:g} deg is outside [0, 360]")
        if not math.isfinite(direction):
            raise RefusedError("yaw direction must be finite")
        self._guided_in_the_air("yaw")
        s = self.state
        start = s.setpoint.yaw_rad if math.isfinite(s.setpoint.yaw_rad) else s.heading_rad
        turn = math.radians(angle_deg) * (-1.0 if direction < 0 else 1.0)
        s.setpoint.yaw_rad = wrap_pi(start + turn if relative else math.radians(angle_deg))
        s.setpoint.yaw_rate_rad_s = math.nan
        self.guided.roi_ned_m = None
        self.say(f"yaw to {math.degrees(s.setpoint.yaw_rad) % 360.0:.0f} deg")

    def guided_roi(self, roi_ned_m: np.ndarray | None) -> None:
        """DO_SET_ROI / DO_SET_ROI_LOCATION in GUIDED: the nose on ``roi_ned_m`` while in
        GUIDED (None: DO_SET_ROI_NONE, the heading stays where it is)."""
        if roi_ned_m is not None and not np.all(np.isfinite(roi_ned_m[:2])):
            raise RefusedError("region of interest must be finite")
        self._guided_in_the_air("region of interest")
        self.guided.roi_ned_m = None if roi_ned_m is None else np.array(roi_ned_m, dtype=float)
        self.say("region of interest cleared" if roi_ned_m is None else
                 f"region of interest {roi_ned_m[0]:.1f} N {roi_ned_m[1]:.1f} E")

    def _guided_in_the_air(self, what: str) -> None:
        v = self.vehicle
        if v.mode is not FlightMode.GUIDED:
            raise RefusedError(f"{what} needs GUIDED mode")
        if not v.armed or v.landed:
            raise RefusedError(f"{what} denied: not in the air", temporary=True)

    def _fly_to(self, target_ned_m: np.ndarray) -> None:
        s = self.state
        s.takeoff_altitude_m = None  # a go-to ends a take-off, as in Copter
        s.attitude_target = None  # a position target replaces an attitude target
        s.setpoint = Setpoint.hold(target_ned_m, s.setpoint.yaw_rad)
