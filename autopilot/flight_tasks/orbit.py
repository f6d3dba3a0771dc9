"""ORBIT (PX4's orbit mode, MAV_CMD_DO_ORBIT): circle a centre at a radius and a speed,
facing as the command asks.

Each period the point on the circle moves on by speed / radius; it is a position
setpoint with its own velocity and centripetal acceleration as feed-forward, shaped like
every other setpoint, so the vehicle first flies to the circle within the vehicle's
limits and then follows it. The speed is kept within what half of MPC_ACC_HOR can turn at
the radius (v^2 / r <= CENTRIPETAL_SHARE * MPC_ACC_HOR).
"""

from __future__ import annotations

import enum
import math

import numpy as np

from autopilot.flight_tasks.shaping import Setpoint
from autopilot.flight_tasks.task import BaseTask, TaskEnv, TaskOutput
from autopilot.refusal import RefusedError
from contracts.frames import wrap_pi
from contracts.modes import FlightMode

DEFAULT_RADIUS_M = 5.0
MIN_RADIUS_M, MAX_RADIUS_M = 1.0, 1000.0
DEFAULT_SPEED_MPS = 1.0
# The circle's centripetal acceleration takes at most this share of MPC_ACC_HOR: the rest
# lets the shaper correct (at the whole limit the vehicle surges round the circle).
CENTRIPETAL_SHARE = 0.5


class OrbitYaw(enum.IntEnum):
    """ORBIT_YAW_BEHAVIOUR (MAVLink's numbers)."""

    FRONT_TO_CENTRE = 0
    INITIAL_HEADING = 1
    UNCONTROLLED = 2  # held as it is
    FRONT_TANGENT = 3
    RC_CONTROLLED = 4  # no sticks in this mode: held as it is


class OrbitTask(BaseTask):
    def __init__(self, env: TaskEnv) -> None:
        super().__init__(env)
        self.centre_ned_m = np.zeros(3)
        self.radius_m = DEFAULT_RADIUS_M  # positive: clockwise seen from above
        self.speed_mps = DEFAULT_SPEED_MPS
        self.yaw_behaviour = OrbitYaw.FRONT_TO_CENTRE
        self._angle_rad = 0.0
        self._held_yaw_rad = 0.0
        self.pending: tuple | None = None  # a request waiting for the mode to start

    def request(self, centre_ned_m: np.ndarray, radius_m: float, speed_mps: float,
                yaw: int) -> None:
        """MAV_CMD_DO_ORBIT's circle (NaN: keep / default), checked before anything
        changes; it applies on entering ORBIT, or now with :meth:`apply` if orbiting."""
        values = (*centre_ned_m, radius_m, speed_mps)
        if any(math.isinf(v) for v in values):
            raise RefusedError("orbit values must be finite or NaN")
        if math.isfinite(radius_m) and not MIN_RADIUS_M <= abs(radius_m) <= MAX_RADIUS_M:
            raise RefusedError(f"orbit radius {radius_m:g} m is outside "
                               f"[{MIN_RADIUS_M:g}, {MAX_RADIUS_M:g}] m")
        if math.isfinite(speed_mps) and not 0.0 < abs(speed_mps) <= 20.0:
            raise RefusedError(f"orbit speed {speed_mps:g} m/s is outside (0, 20]")
        if yaw not in set(OrbitYaw):
            raise RefusedError(f"orbit yaw behaviour {yaw} is unknown")
        if np.any(np.abs(np.nan_to_num(centre_ned_m)) > 1000.0):
            raise RefusedError("orbit centre is more than 1 km from home")
        self.pending = (np.array(centre_ned_m, dtype=float), radius_m, speed_mps,
                         OrbitYaw(yaw))

    def cancel(self) -> None:
        """The request was refused (not in the air): forget it."""
        self.pending = None

    def activate(self, previous: FlightMode, armed: bool) -> None:
        """A request's centre left out is where the vehicle is (MAVLink's rule); without a
        request (a plain mode change) the vehicle orbits where it is, on a circle of the
        default radius whose centre lies north of it."""
        self.centre_ned_m = self.state.stopping_point()
        if self.pending is None:
            self.centre_ned_m[0] += DEFAULT_RADIUS_M
        self.radius_m, self.speed_mps = DEFAULT_RADIUS_M, DEFAULT_SPEED_MPS
        self.yaw_behaviour = OrbitYaw.FRONT_TO_CENTRE
        self.apply()

    def apply(self) -> None:
        """Take the pending request (what it leaves out stays as it is)."""
        s = self.state
        if self.pending is not None:
            centre, radius, speed, yaw = self.pending
            self.pending = None
            # Left out: the centre as it is (entering, where the vehicle is).
            self.centre_ned_m = np.where(np.isfinite(centre), centre, self.centre_ned_m)
            self.radius_m = radius if math.isfinite(radius) else self.radius_m
            self.speed_mps = abs(speed) if math.isfinite(speed) else self.speed_mps
            self.yaw_behaviour = yaw
        here = s.stopping_point() - self.centre_ned_m
        self._angle_rad = math.atan2(here[1], here[0])
        self._held_yaw_rad = s.heading_rad
        s.attitude_target = None
        self.env.say(f"orbit r {self.radius_m:.1f} m at {self.speed_mps:.1f} m/s")

    def update(self) -> TaskOutput:
        s = self.state
        r = abs(self.radius_m)
        speed = min(self.speed_mps, s.limits.xy_vel_max_mps,
                    math.sqrt(CENTRIPETAL_SHARE * s.limits.acc_hor_mps2 * r))
        turn = math.copysign(speed / r, self.radius_m)  # clockwise from above: +angle
        self._angle_rad = wrap_pi(self._angle_rad + turn * s.step_s)
        c, n = math.cos(self._angle_rad), math.sin(self._angle_rad)
        position = self.centre_ned_m + np.array([r * c, r * n, 0.0])
        velocity = np.array([-n, c, 0.0]) * (turn * r)
        accel = np.array([-c, -n, 0.0]) * (turn * turn * r)
        s.setpoint = Setpoint(position, velocity, accel, self._yaw(position, velocity))
        return s.translate()

    def _yaw(self, position: np.ndarray, velocity: np.ndarray) -> float:
        if self.yaw_behaviour is OrbitYaw.FRONT_TO_CENTRE:
            d = self.centre_ned_m - position
            return math.atan2(d[1], d[0])
        if self.yaw_behaviour is OrbitYaw.FRONT_TANGENT:
            return math.atan2(velocity[1], velocity[0])
        return self._held_yaw_rad
