"""AUTO.FOLLOW_TARGET (PX4's Follow Me): keep station on a target that reports where it
is in FOLLOW_TARGET messages (MAVSDK's follow-me plugin, QGroundControl on a phone).

The vehicle flies to FLW_TGT_DST from the target at the follow angle FLW_TGT_FA
(clockwise from the target's course: 0 in front, 90 right, 180 behind), FLW_TGT_HT
above home (FLW_TGT_ALT_M 0 or 1; the ground here is flat) or above the target (2), and
faces the target. Reports come once a second or so: between them the target is carried
on at its velocity (the one reported, or the one its last two positions give), and each
new report is blended in by FLW_TGT_RS (0: taken as it is; towards 1: smoothed more).
The course is the target's direction of travel while it moves (above
COURSE_MIN_SPEED_MPS) and stays as it was while it stands; when it turns, the follow
direction swings round at no more than FLW_TGT_MAX_VEL. The station is a position
setpoint with the target's velocity as feed-forward, shaped like every setpoint. A
target not heard for TARGET_TIMEOUT_S is lost: the vehicle holds where it can stop, and
says so, until reports come back.

Times are sim time: the commander stamps each report with the sim time it arrived at.
"""

from __future__ import annotations

import math

import numpy as np

from autopilot.flight_tasks.shaping import Setpoint
from autopilot.flight_tasks.task import BaseTask, TaskEnv, TaskOutput
from autopilot.refusal import RefusedError
from contracts.frames import wrap_pi
from contracts.modes import FlightMode

TARGET_TIMEOUT_S = 3.0  # no report for this long: the target is lost
COURSE_MIN_SPEED_MPS = 0.5  # slower than this, the target's course is kept as it was
MAX_TARGET_SPEED_MPS = 100.0  # a report faster than this is refused
MAX_TARGET_DISTANCE_M = 10_000.0  # ... and one further than this from home


class FollowTargetTask(BaseTask):
    def __init__(self, env: TaskEnv) -> None:
        super().__init__(env)
        self.target_ned_m: np.ndarray | None = None  # the smoothed target at its report
        self.target_velocity_ned_mps = np.zeros(3)
        self.heard_s = -math.inf  # sim time of the last report
        self.course_rad: float | None = None  # the target's direction of travel
        self._direction_rad: float | None = None  # from the target to the station, flown
        self._lost_said = False
        self._holding = False

    # -- reports -----------------------------------------------------------------------
    def report(self, sim_t_s: float, position_ned_m: np.ndarray,
               velocity_ned_mps: np.ndarray | None) -> None:
        """A FOLLOW_TARGET report in local NED; ``velocity_ned_mps`` None when the target
        gives none. Refused (RefusedError) and ignored when out of range."""
        position = np.asarray(position_ned_m, dtype=float)
        if not np.all(np.isfinite(position)) or \
                np.linalg.norm(position[0:2]) > MAX_TARGET_DISTANCE_M:
            raise RefusedError("follow target: position more than 10 km from home")
        if velocity_ned_mps is not None:
            velocity = np.asarray(velocity_ned_mps, dtype=float)
            if not np.all(np.isfinite(velocity)) or \
                    np.linalg.norm(velocity) > MAX_TARGET_SPEED_MPS:
                raise RefusedError("follow target: velocity not finite or above 100 m/s")
        elif self.target_ned_m is not None and sim_t_s - self.heard_s > 1e-3 and \
                sim_t_s - self.heard_s < TARGET_TIMEOUT_S:
            velocity = (position - self.target_ned_m) / (sim_t_s - self.heard_s)
        else:
            velocity = np.zeros(3)
        if self.target_ned_m is None or sim_t_s - self.heard_s >= TARGET_TIMEOUT_S:
            self.target_ned_m = position
        else:
            predicted = self.predicted(sim_t_s)
            keep = self.state.parameters["FLW_TGT_RS"]
            self.target_ned_m = keep * predicted + (1.0 - keep) * position
        self.target_velocity_ned_mps = velocity
        if math.hypot(velocity[0], velocity[1]) > COURSE_MIN_SPEED_MPS:
            self.course_rad = math.atan2(velocity[1], velocity[0])
        self.heard_s = sim_t_s

    def predicted(self, sim_t_s: float) -> np.ndarray:
        """Where the target is now, carried on from its last report."""
        return self.target_ned_m + self.target_velocity_ned_mps * (sim_t_s - self.heard_s)

    # -- the mode ----------------------------------------------------------------------
    def activate(self, previous: FlightMode, armed: bool) -> None:
        self._direction_rad = None
        self._holding = False
        self._lost_said = False
        self.state.hold_here()
        self.env.say("follow target: waiting for the target" if self.target_ned_m is None
                     else "follow target: following")

    def update(self) -> TaskOutput:
        s = self.state
        t = s.sim_t_s
        if self.target_ned_m is None or t - self.heard_s >= TARGET_TIMEOUT_S:
            if not self._holding:
                self._holding = True
                s.hold_here()
                if self.target_ned_m is not None and not self._lost_said:
                    self._lost_said = True
                    self.env.say(f"follow target: target lost for {TARGET_TIMEOUT_S:g} s: "
                                 "holding", 4)
            return s.translate()
        if self._holding:
            self._holding = False
            if self._lost_said:
                self._lost_said = False
                self.env.say("follow target: target regained")
        p = s.parameters
        target = self.predicted(t)
        here = s.position_ned_m
        if self.course_rad is None:  # a target that has not moved: follow from where we are
            away = here[0:2] - target[0:2]
            wanted = math.atan2(away[1], away[0]) if np.hypot(*away) > 0.1 else 0.0
        else:
            wanted = wrap_pi(self.course_rad + math.radians(p["FLW_TGT_FA"]))
        self._direction_rad = self._swing(wanted, p)
        c, n = math.cos(self._direction_rad), math.sin(self._direction_rad)
        distance = p["FLW_TGT_DST"]
        station = np.array([target[0] + distance * c, target[1] + distance * n,
                            (target[2] if p["FLW_TGT_ALT_M"] == 2.0 else 0.0)
                            - p["FLW_TGT_HT"]])
        velocity = self.target_velocity_ned_mps.copy()
        if p["FLW_TGT_ALT_M"] != 2.0:
            velocity[2] = 0.0
        face = target[0:2] - station[0:2]
        s.setpoint = Setpoint(station, velocity, np.full(3, np.nan),
                              math.atan2(face[1], face[0]))
        s.attitude_target = None
        return s.translate()

    def _swing(self, wanted_rad: float, p: dict[str, float]) -> float:
        """The follow direction, turned towards ``wanted_rad`` at no more than
        FLW_TGT_MAX_VEL round the target."""
        if self._direction_rad is None:
            return wanted_rad
        step = p["FLW_TGT_MAX_VEL"] / p["FLW_TGT_DST"] * self.state.step_s
        error = wrap_pi(wanted_rad - self._direction_rad)
        return wrap_pi(self._direction_rad + max(-step, min(step, error)))
