"""Maintenance commands a ground tool sends before a flight: reboot, sensor calibrations
(PX4's and ArduPilot's), and in the ArduPilot flavour the banner, the compass calibration
and the pre-arm checks, answered as ArduCopter SITL answers them (docs/mavlink.md). Each
handler takes (link, params, now) as commands.py's table and raises RefusedError or
UnsupportedError for a refusal."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import TYPE_CHECKING

from autopilot.commander.failures import UnsupportedError
from autopilot.mavlink.ardupilot import say_banner
from autopilot.mavlink.telemetry import prearm_problem
from autopilot.refusal import RefusedError
from contracts.mavlink import ardupilotmega, mavlink

if TYPE_CHECKING:
    from autopilot.commander.commander import Commander
    from autopilot.mavlink.link import ServerLink


# PREFLIGHT_CALIBRATION: (param index, value) -> the sensor it calibrates.
CALIBRATIONS = {(0, 1.0): "gyro", (1, 1.0): "mag", (2, 1.0): "baro", (4, 1.0): "accel",
                (4, 2.0): "level", (4, 4.0): "accel", (5, 1.0): "airspeed"}


def calibrations(params: list[float]) -> list[str]:
    """The sensors a PREFLIGHT_CALIBRATION asks for, in its parameters' order; a value
    no calibration has (RC, ESC, temperature ones) is unsupported."""
    asked = []
    for i, value in enumerate(params):
        if value == 0.0:
            continue
        sensor = CALIBRATIONS.get((i, value))
        if sensor is None:
            raise UnsupportedError(f"calibration param{i + 1} {value:g} is not supported")
        asked.append(sensor)
    return asked


def reboot_vehicle(v: Commander) -> None:
    """An acknowledged PREFLIGHT_REBOOT_SHUTDOWN, on the ground: the vehicle restarts as
    at boot, its parameters and missions kept (stored, as an autopilot keeps them); the
    home is taken again from the simulator's next sample, as at boot."""
    if v.armed:
        raise RefusedError("reboot denied: armed")
    v.failsafe = None
    v.mode = v.idle_mode
    v.state.takeoff_altitude_m = None
    v.home_known = False
    v.say("rebooted")


class MaintenanceCommands:
    """The maintenance part of the command table."""

    def __init__(self, server: ServerLink) -> None:
        self.server = server

    def table(self) -> dict[int, Callable]:
        """Command id -> handler, for the server's flavour."""
        table: dict[int, Callable] = {
            mavlink.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN: self._reboot,
            mavlink.MAV_CMD_PREFLIGHT_CALIBRATION: self._calibrate,
        }
        if self.server.flavour == "ardupilot":  # ArduPilot's own commands (its dialect)
            table.update({
                ardupilotmega.MAV_CMD_DO_SEND_BANNER: self._banner,
                mavlink.MAV_CMD_RUN_PREARM_CHECKS: self._prearm_checks,
                ardupilotmega.MAV_CMD_DO_START_MAG_CAL: self._start_mag_cal,
                ardupilotmega.MAV_CMD_DO_ACCEPT_MAG_CAL: self._mag_cal_done,
                ardupilotmega.MAV_CMD_DO_CANCEL_MAG_CAL: self._mag_cal_done,
            })
        return table

    def _reboot(self, link, p, now):
        """PREFLIGHT_REBOOT_SHUTDOWN param1 1: the vehicle's state restarts as at boot
        (parameters and missions kept), after the ACK; 0: nothing for the autopilot.
        Refused armed, as Copter and PX4 refuse it; shutdown and bootloader have no
        meaning in a simulation."""
        if not math.isfinite(p[0]) or p[0] not in (0.0, 1.0):
            raise UnsupportedError(f"reboot param1 {p[0]:g}: only 1 (reboot) is supported")
        if p[0] == 0.0:
            return None
        if self.server.vehicle.armed:
            raise RefusedError("reboot denied: armed")
        self.server.reboot_pending = True  # after the ACK has gone out
        return None

    def _calibrate(self, link, p, now):
        """PREFLIGHT_CALIBRATION: simulated sensors need none, so each calibration a tool
        asks completes at once, disarmed (refused armed; params must be finite), with the
        texts the flavour's ground stations watch for: PX4's "[cal] calibration started"
        / "done" per sensor, ArduPilot's barometer lines (its gyro and trim calibrations
        only acknowledge)."""
        if not all(math.isfinite(v) for v in p):
            raise RefusedError("calibration parameters must be finite")
        if self.server.vehicle.armed:
            raise RefusedError("calibration denied: armed")
        asked = calibrations(p)
        if self.server.flavour == "px4":
            for sensor in asked:
                for text in (f"[cal] calibration started: 2 {sensor}",
                             f"[cal] calibration done: {sensor}"):
                    self.server.send_text(link, mavlink.MAV_SEVERITY_INFO, text)
        elif "baro" in asked:
            for text in ("Updating barometer calibration", "Barometer calibration complete"):
                self.server.send_text(link, mavlink.MAV_SEVERITY_INFO, text)

    def _banner(self, link, p, now):
        """DO_SEND_BANNER: the firmware and frame lines."""
        say_banner(self.server, link)

    def _prearm_checks(self, link, p, now):
        """RUN_PREARM_CHECKS: Copter runs them and says what fails ("PreArm: ..."); the
        SYS_STATUS pre-arm bit shows the outcome. Refused armed, as Copter does."""
        vehicle = self.server.vehicle
        if vehicle.armed:
            raise RefusedError("pre-arm checks: armed", temporary=True)
        problem = prearm_problem(vehicle)
        if problem is not None:
            self.server.send_text(link, mavlink.MAV_SEVERITY_CRITICAL, f"PreArm: {problem}")
        return [self.server.telemetry(mavlink.MAVLINK_MSG_ID_SYS_STATUS)]

    def _start_mag_cal(self, link, p, now):
        """DO_START_MAG_CAL: the simulated compass needs none; ArduPilot SITL's finishes
        in seconds with a MAG_CAL_REPORT, ours at once (fitness 0, offsets 0)."""
        if not all(math.isfinite(v) for v in p[:5]):
            raise RefusedError("mag calibration parameters must be finite")
        if self.server.vehicle.armed:
            raise RefusedError("mag calibration denied: armed")
        autosave = p[2] != 0.0
        return [ardupilotmega.MAVLink_mag_cal_report_message(
            0, 1, ardupilotmega.MAG_CAL_SUCCESS, int(autosave), 0.0, 0.0, 0.0, 0.0,
            1.0, 1.0, 1.0, 0.0, 0.0, 0.0, 1.0, ardupilotmega.MAV_SENSOR_ROTATION_NONE,
            ardupilotmega.MAV_SENSOR_ROTATION_NONE, 1.0)]

    def _mag_cal_done(self, link, p, now):
        """ACCEPT / CANCEL_MAG_CAL: the calibration finished when it started."""
        return None
