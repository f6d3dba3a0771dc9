"""Setpoint streams from ground tools (SET_POSITION_TARGET_LOCAL_NED / GLOBAL_INT,
SET_ATTITUDE_TARGET, MANUAL_CONTROL) to the vehicle; refusals said at most once a
second."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

from autopilot.flight_tasks.sticks import sticks_from_manual_control
from autopilot.mavlink.offboard import global_setpoint, local_setpoint
from autopilot.refusal import RefusedError
from contracts.vectors import MEASUREMENT

if TYPE_CHECKING:
    from autopilot.mavlink.server import GroundLink, MavlinkServer

# Attitude-target type_mask bits (ATTITUDE_TARGET_TYPEMASK).
BODY_RATES_IGNORE = 0b111
THRUST_IGNORE = 1 << 6
ATTITUDE_IGNORE = 1 << 7
REFUSAL_EVERY_S = 1.0  # setpoints stream at 20 Hz and more: one STATUSTEXT per second


class SetpointProtocol:
    def __init__(self, server: MavlinkServer) -> None:
        self.server = server
        self._last_refusal_s = -math.inf

    def handlers(self) -> dict[str, Callable]:
        return {"SET_POSITION_TARGET_LOCAL_NED": self.on_local,
                "SET_POSITION_TARGET_GLOBAL_INT": self.on_global,
                "SET_ATTITUDE_TARGET": self.on_attitude, "MANUAL_CONTROL": self.on_manual}

    def on_local(self, link: GroundLink, address, msg, now: float) -> None:
        v = self.server.vehicle
        here = (v.measurement[MEASUREMENT.position_ned_m] if v.measurement is not None
                else np.zeros(3))
        try:
            setpoint = local_setpoint(
                msg.coordinate_frame, msg.type_mask, (msg.x, msg.y, msg.z),
                (msg.vx, msg.vy, msg.vz), (msg.afx, msg.afy, msg.afz), msg.yaw, msg.yaw_rate,
                here, v.heading_rad)
            v.position_setpoint(now, setpoint)
        except RefusedError as exc:
            self._refuse(link, address, str(exc), now)

    def on_global(self, link: GroundLink, address, msg, now: float) -> None:
        try:
            setpoint = global_setpoint(
                self.server.vehicle.home, msg.coordinate_frame, msg.type_mask, msg.lat_int,
                msg.lon_int, msg.alt, (msg.vx, msg.vy, msg.vz), (msg.afx, msg.afy, msg.afz),
                msg.yaw, msg.yaw_rate)
            self.server.vehicle.position_setpoint(now, setpoint)
        except RefusedError as exc:
            self._refuse(link, address, str(exc), now)

    def on_attitude(self, link: GroundLink, address, msg, now: float) -> None:
        mask = msg.type_mask
        try:
            if mask & BODY_RATES_IGNORE != BODY_RATES_IGNORE:
                raise RefusedError("body-rate setpoints are not supported")
            self.server.vehicle.attitude_setpoint(
                now, None if mask & ATTITUDE_IGNORE else tuple(msg.q),
                None if mask & THRUST_IGNORE else msg.thrust)
        except RefusedError as exc:
            self._refuse(link, address, str(exc), now)

    def on_manual(self, link: GroundLink, address, msg, now: float) -> None:
        """MANUAL_CONTROL (QGroundControl's virtual joystick, MAVSDK's manual control)."""
        try:
            sticks = sticks_from_manual_control(msg.x, msg.y, msg.z, msg.r)
        except RefusedError as exc:
            self._refuse(link, address, str(exc), now)
            return
        self.server.vehicle.manual_input(now, sticks)

    def _refuse(self, link: GroundLink, address, text: str, now: float) -> None:
        if now - self._last_refusal_s >= REFUSAL_EVERY_S:
            self._last_refusal_s = now
            self.server.send_text(link, 4, f"setpoint refused: {text}", address)
