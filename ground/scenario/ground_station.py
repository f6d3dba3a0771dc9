"""The run's ground station as a ground tool: a scenario's ``[ground_station]`` table.

A person's ground tool (QGroundControl, a MAVSDK script) sends the vehicle a heartbeat
every second and, in offboard, a stream of setpoints; a lost radio or a crashed script
stops them. A scenario rehearses that: during the run a real MAVLink client on the
autopilot's ground link sends what the table says, and falls silent in its windows, so
the vehicle's link failsafes (COM_DL_LOSS_T / NAV_DLL_ACT, COM_OF_LOSS_T / COM_OBL_ACT)
act as they would in the field.

    [ground_station]
    heartbeat_hz = 1.0          # a GCS heartbeat (0: none)
    offboard_at_s = 4.0         # stream the hover point and switch to OFFBOARD at 4 s
    [[ground_station.silence]]
    what = "setpoints"          # "heartbeat", "setpoints" or "all" (a lost radio)
    start_s = 10.0
    end_s = 16.0

Times are seconds after the vehicle is released, on the wall clock as a ground tool's
are (the failsafes time them on the wall clock too), but never ahead of the vehicle's own
clock as its telemetry shows it (``time_boot_ms``): a simulator that took its first step
late, or stalled and went on behind the wall clock, would otherwise see the plan's events
early in sim time, where the run's expectations judge them. Fly such a scenario in real
time (``--realtime``), so that they match the run's sim time.
"""

from __future__ import annotations

import contextlib
import math
import threading
import time
from collections import deque
from dataclasses import dataclass
from typing import Any

from contracts.mavlink import mavlink
from contracts.modes import PX4_MODES, FlightMode
from contracts.toml_tables import array_of_tables, check_fields, number

GCS_SYSID = 255  # QGroundControl's system id
SILENCE_KINDS = ("heartbeat", "setpoints", "all")
_KEYS = {"heartbeat_hz", "offboard_at_s", "setpoint_hz", "silence"}
_SILENCE_KEYS = {"what", "start_s", "end_s"}
# Position only: the rest of SET_POSITION_TARGET_LOCAL_NED is ignored.
_POSITION_ONLY = 0b0000_1001_1111_1000


@dataclass(frozen=True)
class Silence:
    """From ``start_s`` to ``end_s`` the ground station does not send ``what``."""

    what: str
    start_s: float
    end_s: float

    def covers(self, what: str, t_s: float) -> bool:
        return self.what in (what, "all") and self.start_s <= t_s < self.end_s


@dataclass(frozen=True)
class GroundStationPlan:
    heartbeat_hz: float = 1.0
    offboard_at_s: float | None = None  # when to switch to OFFBOARD (None: never)
    setpoint_hz: float = 20.0
    silences: tuple[Silence, ...] = ()

    def silent(self, what: str, t_s: float) -> bool:
        return any(s.covers(what, t_s) for s in self.silences)


def parse_ground_station(table: Any, duration_s: float) -> GroundStationPlan | None:
    """The ``[ground_station]`` table, checked; None when the scenario has none."""
    if table is None:
        return None
    if not isinstance(table, dict):
        raise ValueError("[ground_station] must be a table")
    check_fields(table, _KEYS, "ground_station")
    heartbeat_hz = _number(table, "heartbeat_hz", 1.0, 0.0, 50.0)
    setpoint_hz = _number(table, "setpoint_hz", 20.0, 2.0, 100.0)
    offboard = table.get("offboard_at_s")
    if offboard is not None:
        offboard = _number(table, "offboard_at_s", 0.0, 0.0, duration_s)
    out = []
    for where, item in array_of_tables(table, "silence", "ground_station.silence",
                                       _SILENCE_KEYS):
        what = item.get("what", "all")
        if what not in SILENCE_KINDS:
            raise ValueError(f"{where}: what must be one of {', '.join(SILENCE_KINDS)}, "
                             f"got {what!r}")
        if what == "setpoints" and offboard is None:
            raise ValueError(f"{where}: no setpoints to silence (give offboard_at_s)")
        start = _number(item, "start_s", None, 0.0, duration_s)
        end = _number(item, "end_s", duration_s, start, math.inf)
        out.append(Silence(what, start, end))
    return GroundStationPlan(heartbeat_hz, offboard, setpoint_hz, tuple(out))


def _number(table: dict, key: str, default: float | None, low: float, high: float) -> float:
    value = table.get(key, default)
    if value is None:
        raise ValueError(f"ground_station: {key} is required")
    return number(value, f"ground_station: {key}", low, high)


SENT_AT_MAX = 4096  # the latest sendings kept in GroundStation.sent_at (minutes at 40 Hz)


class GroundStation:
    """A GCS on a thread: heartbeats, the hover setpoint stream and the switch to
    OFFBOARD, each silenced in the plan's windows. What it sent is counted in ``sent``,
    and the latest sendings are in ``sent_at`` with the plan time they went out at (the
    station's own clock: what it did, whenever a reader gets to it)."""

    def __init__(self, plan: GroundStationPlan, port: int, vehicle_sysid: int,
                 hover_ned_m: tuple[float, float, float], yaw_rad: float) -> None:
        from pymavlink import mavutil

        self.plan = plan
        self.conn = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}",
                                               source_system=GCS_SYSID,
                                               source_component=mavlink.MAV_COMP_ID_MISSIONPLANNER)
        self.target = vehicle_sysid
        self.hover_ned_m = hover_ned_m
        self.yaw_rad = yaw_rad
        self.sent = {"heartbeat": 0, "setpoints": 0, "set_mode": 0}
        self.sent_at: deque[tuple[str, float]] = deque(maxlen=SENT_AT_MAX)  # (kind, plan s)
        self.mode_acked = False
        self.error: str | None = None  # why the thread stopped early
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="ground-station", daemon=True)
        self._t0 = 0.0
        self._heard = False  # the vehicle's clock yet
        self._next_beat = self._next_setpoint = 0.0  # plan times [s] of the next sendings
        self._next_mode = plan.offboard_at_s if plan.offboard_at_s is not None else math.inf

    def start(self) -> None:
        self._t0 = time.monotonic()
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=2.0)
        self.conn.close()

    def _send(self, msg) -> None:
        with contextlib.suppress(OSError):  # the vehicle is gone: the run's end says so
            self.conn.mav.send(msg)

    def _run(self) -> None:
        try:
            self._loop()
        except Exception as exc:  # noqa: BLE001 (the run reports it: ``error``)
            self.error = f"{type(exc).__name__}: {exc}"

    def _loop(self) -> None:
        while not self._stop.is_set():
            self.step(time.monotonic() - self._t0)
            self._stop.wait(0.005)

    def step(self, t: float) -> None:
        """One pass at plan time ``t`` [s]: what is due goes out (one of each kind; what
        fell due in a silence is skipped), then what the vehicle said is read. The thread
        calls it every 5 ms; a test calls it on its own clock."""
        plan = self.plan
        if plan.heartbeat_hz > 0 and t >= self._next_beat:
            self._next_beat += 1.0 / plan.heartbeat_hz
            if not plan.silent("heartbeat", t):
                self._send(mavlink.MAVLink_heartbeat_message(
                    mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0,
                    mavlink.MAV_STATE_ACTIVE, 3))
                self.sent["heartbeat"] += 1
                self.sent_at.append(("heartbeat", t))
        if plan.offboard_at_s is not None and t >= self._next_setpoint:
            self._next_setpoint += 1.0 / plan.setpoint_hz
            if not plan.silent("setpoints", t):
                self._send(mavlink.MAVLink_set_position_target_local_ned_message(
                    int(t * 1000), self.target, 1, mavlink.MAV_FRAME_LOCAL_NED,
                    _POSITION_ONLY, *self.hover_ned_m, 0, 0, 0, 0, 0, 0,
                    self.yaw_rad, 0))
                self.sent["setpoints"] += 1
                self.sent_at.append(("setpoints", t))
        if t >= self._next_mode and not self.mode_acked:
            self._next_mode = t + 0.5  # again until acknowledged, as ground tools retry
            if not plan.silent("all", t):
                self._send(mavlink.MAVLink_command_long_message(
                    self.target, 1, mavlink.MAV_CMD_DO_SET_MODE, 0,
                    mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
                    *PX4_MODES[FlightMode.OFFBOARD], 0, 0, 0, 0))
                self.sent["set_mode"] += 1
                self.sent_at.append(("set_mode", t))
        self._read()

    def plan_time(self, now_s: float) -> float:
        """The plan's time [s] at ``now_s`` on time.monotonic."""
        return now_s - self._t0

    def hear_vehicle_time(self, boot_ms: int, now_s: float) -> None:
        """The plan runs on the vehicle's clock: set to it when the vehicle is first heard
        (a station started late, beside busy work 2 s after the simulator was released,
        had flown its whole plan 2 s behind the vehicle), then held back to it whenever
        the vehicle falls behind (a simulator that stalled, or a message heard late)."""
        vehicle_t0 = now_s - boot_ms / 1e3
        self._t0 = vehicle_t0 if not self._heard else max(self._t0, vehicle_t0)
        self._heard = True

    def _read(self) -> None:
        """Take what the vehicle sent (so the socket never fills); note the mode's ack;
        keep the plan on the vehicle's clock."""
        for _ in range(200):  # a budget: the vehicle streams telemetry at up to 50 Hz
            msg = self.conn.recv_match(blocking=False)
            if msg is None:
                return
            boot_ms = getattr(msg, "time_boot_ms", None)
            if boot_ms is not None and msg.get_srcSystem() == self.target:
                self.hear_vehicle_time(boot_ms, time.monotonic())
            if msg.get_type() == "COMMAND_ACK" and \
                    msg.command == mavlink.MAV_CMD_DO_SET_MODE and \
                    msg.result == mavlink.MAV_RESULT_ACCEPTED:
                self.mode_acked = True

