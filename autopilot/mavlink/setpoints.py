"""Setpoint streams from ground tools (SET_POSITION_TARGET_LOCAL_NED / GLOBAL_INT,
SET_ATTITUDE_TARGET, MANUAL_CONTROL, and a Follow Me target's FOLLOW_TARGET) to the
vehicle, and in the ArduPilot flavour RC_CHANNELS_OVERRIDE, with MANUAL_CONTROL onto the
same channels (autopilot/commander/rc.py); refusals said at most once a second."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

from autopilot.commander.rc import manual_control_channels
from autopilot.flight_tasks.sticks import sticks_from_manual_control
from autopilot.mavlink.offboard import global_setpoint, local_setpoint
from autopilot.refusal import RefusedError
from contracts.mavlink import mavlink
from contracts.vectors import MEASUREMENT

if TYPE_CHECKING:
    from autopilot.mavlink.link import GroundLink, ServerLink

# Attitude-target type_mask bits (ATTITUDE_TARGET_TYPEMASK).
BODY_RATES_IGNORE = 0b111
THRUST_IGNORE = 1 << 6
ATTITUDE_IGNORE = 1 << 7
REFUSAL_EVERY_S = 1.0  # setpoints stream at 20 Hz and more: one STATUSTEXT per second
# FOLLOW_TARGET est_capabilities bits: position, velocity.
TARGET_HAS_POSITION, TARGET_HAS_VELOCITY = 1 << 0, 1 << 1


class SetpointProtocol:
    def __init__(self, server: ServerLink) -> None:
        self.server = server
        self._last_refusal_s = -math.inf

    def handlers(self) -> dict[str, Callable]:
        return {"SET_POSITION_TARGET_LOCAL_NED": self.on_local,
                "SET_POSITION_TARGET_GLOBAL_INT": self.on_global,
                "SET_ATTITUDE_TARGET": self.on_attitude, "MANUAL_CONTROL": self.on_manual,
                "FOLLOW_TARGET": self.on_follow_target,
                **({"RC_CHANNELS_OVERRIDE": self.on_rc_override}
                   if self.server.flavour == "ardupilot" else {})}

    def on_local(self, link: GroundLink, address, msg, now: float) -> None:
        v = self.server.vehicle
        here = (v.measurement[MEASUREMENT.position_ned_m] if v.measurement is not None
                else np.zeros(3))
        try:
            setpoint = local_setpoint(
                msg.coordinate_frame, msg.type_mask, (msg.x, msg.y, msg.z),
                (msg.vx, msg.vy, msg.vz), (msg.afx, msg.afy, msg.afz), msg.yaw, msg.yaw_rate,
                here, v.heading_rad)
            v.inputs.position_setpoint(now, setpoint)
        except RefusedError as exc:
            self._refuse(link, address, str(exc), now)

    def on_global(self, link: GroundLink, address, msg, now: float) -> None:
        try:
            setpoint = global_setpoint(
                self.server.vehicle.places, msg.coordinate_frame, msg.type_mask, msg.lat_int,
                msg.lon_int, msg.alt, (msg.vx, msg.vy, msg.vz), (msg.afx, msg.afy, msg.afz),
                msg.yaw, msg.yaw_rate)
            self.server.vehicle.inputs.position_setpoint(now, setpoint)
        except RefusedError as exc:
            self._refuse(link, address, str(exc), now)

    def on_attitude(self, link: GroundLink, address, msg, now: float) -> None:
        mask = msg.type_mask
        try:
            if mask & BODY_RATES_IGNORE != BODY_RATES_IGNORE:
                raise RefusedError("body-rate setpoints are not supported")
            self.server.vehicle.inputs.attitude_setpoint(
                now, None if mask & ATTITUDE_IGNORE else tuple(msg.q),
                None if mask & THRUST_IGNORE else msg.thrust)
        except RefusedError as exc:
            self._refuse(link, address, str(exc), now)

    def _from_my_gcs(self, msg, now: float) -> bool:
        """ArduPilot takes RC only from SYSID_MYGCS (others are ignored, not answered); a
        frame from it counts as the ground station's heartbeat (sysid_myggcs_seen)."""
        if msg.get_srcSystem() != self.server.vehicle.parameters["SYSID_MYGCS"]:
            return False
        self.server.vehicle.inputs.gcs_heartbeat(now)
        return True

    def on_rc_override(self, link: GroundLink, address, msg, now: float) -> None:
        """RC_CHANNELS_OVERRIDE (DroneKit's vehicle.channels.overrides, MAVProxy's rc)."""
        if not self._from_my_gcs(msg, now):
            return
        channels = [getattr(msg, f"chan{i}_raw") for i in range(1, 19)]
        try:
            self.server.vehicle.inputs.rc_override(now, channels)
        except RefusedError as exc:
            self._refuse(link, address, str(exc), now)

    def on_manual(self, link: GroundLink, address, msg, now: float) -> None:
        """MANUAL_CONTROL (QGroundControl's virtual joystick, MAVSDK's manual control); in
        the ArduPilot flavour an override of channels 1-4, from SYSID_MYGCS only."""
        if self.server.flavour == "ardupilot":
            if msg.target != link.mav.srcSystem or not self._from_my_gcs(msg, now):
                return
            try:
                self.server.vehicle.inputs.rc_override(
                    now, manual_control_channels(msg.x, msg.y, msg.z, msg.r))
            except RefusedError as exc:
                self._refuse(link, address, str(exc), now)
            return
        try:
            sticks = sticks_from_manual_control(msg.x, msg.y, msg.z, msg.r)
        except RefusedError as exc:
            self._refuse(link, address, str(exc), now)
            return
        self.server.vehicle.inputs.manual_input(now, sticks)

    def on_follow_target(self, link: GroundLink, address, msg, now: float) -> None:
        """FOLLOW_TARGET (MAVSDK's follow-me plugin): the target's latitude, longitude and
        altitude AMSL, with its NED velocity when est_capabilities says it has one."""
        v = self.server.vehicle
        try:
            if not msg.est_capabilities & TARGET_HAS_POSITION:
                raise RefusedError("follow target: the report has no position")
            lat, lon = msg.lat * 1e-7, msg.lon * 1e-7
            if not (abs(lat) <= 90.0 and abs(lon) <= 180.0 and math.isfinite(msg.alt)):
                raise RefusedError(f"follow target: {lat:g}, {lon:g}, {msg.alt:g} m is not "
                                   "a position on Earth")
            position = v.places.ned_from_global(mavlink.MAV_FRAME_GLOBAL, lat, lon, msg.alt)
            # MAVSDK sets only the position bit but sends the velocity its caller gave: a
            # finite velocity counts unless it is all zeros without the velocity bit.
            velocity = np.array(msg.vel, dtype=float)
            if not np.all(np.isfinite(velocity)) or (
                    not msg.est_capabilities & TARGET_HAS_VELOCITY and not np.any(velocity)):
                velocity = None  # the task estimates it from the positions
            v.inputs.follow_target(position, velocity)
        except RefusedError as exc:
            self._refuse(link, address, str(exc), now)

    def _refuse(self, link: GroundLink, address, text: str, now: float) -> None:
        if now - self._last_refusal_s >= REFUSAL_EVERY_S:
            self._last_refusal_s = now
            self.server.send_text(link, 4, f"setpoint refused: {text}", address)
