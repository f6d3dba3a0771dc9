"""COMMAND_LONG / COMMAND_INT (and the legacy SET_MODE) for the vehicle: each command
acknowledged with the MAV_RESULT a ground tool expects, refusals explained in STATUSTEXT.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import TYPE_CHECKING

from autopilot.commander.failures import UnsupportedError
from autopilot.commander.personality import FORCE_ARM_MAGIC
from autopilot.mavlink.guided import copter_commands
from autopilot.mavlink.home_command import do_set_home
from autopilot.mavlink.maintenance import MaintenanceCommands
from autopilot.mavlink.telemetry import (
    DEFAULT_STREAMS,
    home_position,
    mission_current,
    producible,
    stored_seq,
)
from autopilot.navigator.mission_store import ItemError
from autopilot.refusal import RefusedError
from contracts.mavlink import GLOBAL_FRAMES, mavlink
from contracts.modes import FlightMode, mode_from_custom, px4_custom_mode_from_command

if TYPE_CHECKING:
    from autopilot.mavlink.link import GroundLink, ServerLink

FORCE_DISARM_MAGIC = 21196
INT32_MAX = 2**31 - 1
# What Copter answers MAV_RESULT_FAILED when it refuses (GCS_MAVLink_Copter.cpp).
FAILS_IN_COPTER = (mavlink.MAV_CMD_COMPONENT_ARM_DISARM, mavlink.MAV_CMD_NAV_TAKEOFF,
                   mavlink.MAV_CMD_DO_SET_MODE, mavlink.MAV_CMD_DO_FLIGHTTERMINATION,
                   mavlink.MAV_CMD_CONDITION_YAW, mavlink.MAV_CMD_DO_SET_ROI,
                   mavlink.MAV_CMD_DO_SET_ROI_LOCATION, mavlink.MAV_CMD_DO_SET_ROI_NONE)


class CommandProtocol:
    """Maps commands to vehicle calls; a handler returns messages to send after the ACK."""

    def __init__(self, server: ServerLink) -> None:
        self.server = server
        self.handled = 0
        self.table: dict[int, Callable] = {
            mavlink.MAV_CMD_COMPONENT_ARM_DISARM: self._arm,
            mavlink.MAV_CMD_NAV_TAKEOFF: self._takeoff,
            mavlink.MAV_CMD_NAV_LAND: self._land,
            mavlink.MAV_CMD_DO_SET_MODE: self._set_mode,
            mavlink.MAV_CMD_REQUEST_MESSAGE: self._request_message,
            mavlink.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES: lambda *_: [
                self.server.telemetry(mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION)],
            mavlink.MAV_CMD_GET_HOME_POSITION: lambda *_: [
                home_position(self.server.vehicle.places)],
            mavlink.MAV_CMD_SET_MESSAGE_INTERVAL: self._message_interval,
            mavlink.MAV_CMD_DO_SET_MISSION_CURRENT: self._set_mission_current,
            mavlink.MAV_CMD_MISSION_START: self._mission_start,
            mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH: self._return,
            mavlink.MAV_CMD_DO_REPOSITION: self._reposition,
            mavlink.MAV_CMD_DO_ORBIT: self._orbit,
            mavlink.MAV_CMD_DO_CHANGE_SPEED: self._change_speed,
            mavlink.MAV_CMD_INJECT_FAILURE: self._inject_failure,
            **MaintenanceCommands(server).table(),
        }
        # Copter's own commands (none for PX4).
        self.table.update(copter_commands(server, lambda: self.frame))
        self.table[mavlink.MAV_CMD_DO_SET_HOME] = lambda link, p, now: do_set_home(
            self.server.vehicle, self.frame, p)
        self.frame = mavlink.MAV_FRAME_GLOBAL  # the command's frame (COMMAND_LONG: AMSL)

    def handlers(self) -> dict[str, Callable]:
        return {"COMMAND_LONG": self.on_command_long, "COMMAND_INT": self.on_command_int,
                "SET_MODE": self.on_set_mode}

    def on_command_long(self, link: GroundLink, address, msg, now: float) -> None:
        params = [msg.param1, msg.param2, msg.param3, msg.param4, msg.param5, msg.param6,
                  msg.param7]
        self.frame = mavlink.MAV_FRAME_GLOBAL
        self.command(link, address, msg, msg.command, params, now)

    def on_command_int(self, link: GroundLink, address, msg, now: float) -> None:
        # INT32_MAX in x or y: "not given" (MAVLink's COMMAND_INT convention).
        params = [msg.param1, msg.param2, msg.param3, msg.param4,
                  math.nan if msg.x == INT32_MAX else msg.x * 1e-7,
                  math.nan if msg.y == INT32_MAX else msg.y * 1e-7, msg.z]
        self.frame = msg.frame
        self.command(link, address, msg, msg.command, params, now)

    def on_set_mode(self, link: GroundLink, address, msg, now: float) -> None:
        # Deprecated but sent by older tools (MAVProxy for ArduPilot); acknowledged as
        # DO_SET_MODE, as ArduPilot does.
        self.command(link, address, msg, mavlink.MAV_CMD_DO_SET_MODE,
                     [float(msg.base_mode), float(msg.custom_mode), 0.0, 0, 0, 0, 0], now)

    def command(self, link: GroundLink, address, msg, command: int, params: list[float],
                now: float) -> None:
        self.handled += 1
        handler = self.table.get(command)
        if handler is None:
            self.ack(link, address, msg, command, mavlink.MAV_RESULT_UNSUPPORTED)
            return
        try:
            replies = handler(link, params, now)
        except UnsupportedError as exc:
            self.ack(link, address, msg, command, mavlink.MAV_RESULT_UNSUPPORTED, str(exc))
            return
        except RefusedError as exc:
            result = (mavlink.MAV_RESULT_TEMPORARILY_REJECTED if exc.temporary
                      else mavlink.MAV_RESULT_DENIED)
            if self.server.vehicle.personality.refusals_fail and (
                    exc.failed or command in FAILS_IN_COPTER):
                result = mavlink.MAV_RESULT_FAILED
            self.ack(link, address, msg, command, result, str(exc))
            return
        self.ack(link, address, msg, command, mavlink.MAV_RESULT_ACCEPTED)
        for reply in replies or ():
            self.server.send(link, reply, address)

    def ack(self, link: GroundLink, address, msg, command: int, result: int,
            text: str | None = None) -> None:
        self.server.send(link, mavlink.MAVLink_command_ack_message(
            command, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent()), address)
        if text:
            severity = 6 if result == mavlink.MAV_RESULT_ACCEPTED else 4
            self.server.send_text(link, severity, text, address)

    # -- the commands --------------------------------------------------------------------
    def _inject_failure(self, link, p, now):
        self.server.vehicle.inject_failure(p[0], p[1], p[2])

    def _arm(self, link, p, now):
        """param1 1 arms, 0 disarms; param2 21196 forces a disarm in the air, and in
        Copter's flavour 2989 forces an arm (its mode and ground checks skipped)."""
        vehicle = self.server.vehicle
        if p[0] == 1.0:
            vehicle.arm(now, force=vehicle.personality.force_arm and p[1] == FORCE_ARM_MAGIC)
        elif p[0] == 0.0:
            vehicle.disarm(force=p[1] == FORCE_DISARM_MAGIC)
        else:
            raise RefusedError(f"arm param1 must be 0 or 1, got {p[0]:g}")

    def _takeoff(self, link, p, now):
        altitude = p[6]
        if math.isnan(altitude):
            relative = None
        elif self.server.flavour == "px4":
            relative = altitude - self.server.vehicle.places.home.alt_amsl_m  # PX4: AMSL
        else:
            relative = altitude  # ArduPilot reads it above home
        self.server.vehicle.takeoff(relative)

    def _land(self, link, p, now):
        self.server.vehicle.land()

    def _set_mode(self, link, p, now):
        base, main, sub = p[0], p[1], p[2]
        if not all(math.isfinite(v) for v in (base, main, sub)):
            raise RefusedError("mode parameters must be finite")
        if not int(base) & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            raise RefusedError("only custom modes are supported")
        flavour = self.server.flavour
        number = int(main) if flavour == "ardupilot" else px4_custom_mode_from_command(main, sub)
        mode = mode_from_custom(flavour, number)
        if mode is None:
            label = f"{main:g}" if flavour == "ardupilot" else f"{main:g}/{sub:g}"
            raise RefusedError(self.server.vehicle.personality.unflown_mode(number, label))
        self.server.vehicle.set_mode(mode, now)

    def _set_mission_current(self, link, p, now):
        """The mission item to go on from (MAVProxy's ``wp set`` sends this first)."""
        seq = int(p[0]) if math.isfinite(p[0]) and p[0] == int(p[0]) else -1
        try:
            self.server.vehicle.mission.set_current(stored_seq(self.server.flavour, seq))
        except ItemError as exc:
            raise RefusedError(str(exc)) from None
        return [mission_current(self.server.vehicle, self.server.flavour)]

    def _mission_start(self, link, p, now):
        if not (math.isfinite(p[0]) and p[0] == int(p[0])):
            raise RefusedError(f"mission start: item {p[0]:g} is not a whole number")
        self.server.vehicle.auto.start_mission(int(p[0]), now)

    def _return(self, link, p, now):
        self.server.vehicle.set_mode(FlightMode.RTL, now)

    def _change_speed(self, link, p, now):
        """DO_CHANGE_SPEED (QGroundControl's "change speed"): param2 in m/s, -1 no change."""
        self.server.vehicle.auto.change_speed(p[1])

    def _reposition(self, link, p, now):
        """DO_REPOSITION (QGroundControl's "go to location", MAVSDK's goto_location):
        param1 speed (-1: default), param4 yaw [rad] (NaN: keep), latitude, longitude,
        altitude (AMSL, or above home in a relative frame; NaN keeps what the vehicle
        has)."""
        if self.frame not in GLOBAL_FRAMES:
            raise RefusedError(f"go-to frame {self.frame} is not supported")
        lat, lon, alt = p[4], p[5], p[6]
        if any(math.isinf(v) for v in (p[0], p[3], lat, lon, alt)):
            raise RefusedError("go-to values must be finite or NaN")
        if math.isfinite(lat) != math.isfinite(lon):
            raise RefusedError("go-to gives latitude without longitude or the reverse")
        if math.isfinite(lat) and (abs(lat) > 90.0 or abs(lon) > 180.0):
            raise RefusedError(f"go-to latitude/longitude {lat:g}, {lon:g} is not on Earth")
        target = self.server.vehicle.places.ned_from_global(self.frame, lat, lon, alt)
        vehicle = self.server.vehicle
        if vehicle.personality.guided_requests:  # Copter: a GUIDED go-to
            flags = int(p[1]) if math.isfinite(p[1]) and 0 <= p[1] < 2**31 else 0
            vehicle.auto.guided_reposition(
                target, bool(flags & mavlink.MAV_DO_REPOSITION_FLAGS_CHANGE_MODE), now)
            return
        # param4 in radians, as PX4 and MAVSDK read it (the MAVLink spec said degrees
        # until 2025 and now says radians too); NaN keeps the heading.
        yaw = p[3]
        self.server.vehicle.auto.reposition(target, yaw, p[0] if math.isfinite(p[0]) else -1.0)

    def _orbit(self, link, p, now):
        """DO_ORBIT (MAVSDK's do_orbit): param1 radius [m] (negative: counter-clockwise),
        param2 speed [m/s], param3 yaw behaviour, centre latitude, longitude, altitude
        (NaN: where the vehicle is). The altitude is AMSL whatever the frame, as PX4 reads
        it (MAVSDK sends an AMSL altitude in a relative-altitude frame)."""
        if self.frame not in GLOBAL_FRAMES:
            raise RefusedError(f"orbit frame {self.frame} is not supported")
        lat, lon = p[4], p[5]
        if math.isfinite(lat) != math.isfinite(lon):
            raise RefusedError("orbit gives latitude without longitude or the reverse")
        if math.isfinite(lat) and (abs(lat) > 90.0 or abs(lon) > 180.0):
            raise RefusedError(f"orbit latitude/longitude {lat:g}, {lon:g} is not on Earth")
        if any(math.isinf(v) for v in (p[2], *p[4:7])):
            raise RefusedError("orbit values must be finite or NaN")
        vehicle = self.server.vehicle
        task = vehicle.tasks[FlightMode.ORBIT]
        task.request(vehicle.places.ned_from_global(mavlink.MAV_FRAME_GLOBAL, lat, lon, p[6]),
                     p[0], p[1], 0 if math.isnan(p[2]) else int(p[2]))
        if vehicle.mode is FlightMode.ORBIT:
            task.apply()
            return
        try:
            vehicle.set_mode(FlightMode.ORBIT, now)
        except RefusedError:
            task.cancel()
            raise

    def _request_message(self, link, p, now):
        msg_id = int(p[0]) if math.isfinite(p[0]) else -1
        if msg_id not in producible(self.server.flavour):
            raise RefusedError(f"message {p[0]:g} is not produced")
        return [self.server.telemetry(msg_id)]

    def _message_interval(self, link, p, now):
        msg_id, interval_us = int(p[0]) if math.isfinite(p[0]) else -1, p[1]
        if msg_id not in producible(self.server.flavour):
            raise RefusedError(f"message {p[0]:g} is not produced")
        if not math.isfinite(interval_us):
            raise RefusedError("interval must be finite")
        if interval_us == -1:
            link.intervals_s.pop(msg_id, None)
        elif interval_us == 0:
            link.intervals_s[msg_id] = DEFAULT_STREAMS.get(msg_id, 1.0)
        elif interval_us > 0:
            link.intervals_s[msg_id] = max(interval_us * 1e-6, 0.005)
        else:
            raise RefusedError(f"interval {interval_us:g} us is invalid")
        link.next_due_s.pop(msg_id, None)
