"""A 30 ms stop of the autopilot process (SIGSTOP) on a real-time orbit: what it costs the
vehicle's speed, judged from the simulator's truth in the run's log.

Real processes in real time (simulator, autopilot, logger), a pymavlink ground tool:
take off, DO_ORBIT 4 m round a centre 6 m north at 1.5 m/s, onto the circle, then stop
the autopilot for 30 ms three times, 4 s apart. The simulator flies on with the last
command; the autopilot, resumed, steps once late and goes on. Before the fixes a stop
cost 28-38 mm/s for a second (the setpoints went on a period per step whatever was
lost) and 15 mm/s when the instant after the late step flew the same sample again
(docs/mavlink.md, Time). A stop is judged only when the machine did not disturb the
flight around it itself (docs there too: on the normal scheduler under load it does).
"""
from __future__ import annotations

import json
import math
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from contracts.frames import DEFAULT_HOME
from contracts.telemetry import STATE, vehicle_key
from ground.record.run_files import control_records, iter_messages
from ground.run.children import free_tcp_port
from tests.harness import GroundTool, mavutil, start_processes

pytestmark = [pytest.mark.process, pytest.mark.alone]  # measures the speed a stall costs

M = mavutil.mavlink
CENTRE_NORTH_M, RADIUS_M, SPEED_MPS = 6.0, 4.0, 1.5
STOP_S = 0.03
STOPS_AT_S = (10.0, 14.0, 18.0)  # vehicle time after the orbit command
WINDOW_S = 2.0  # judged before and after each stop
TIMER_PRIORITY = 60  # SCHED_FIFO of this process while it times a stop, if allowed
PERIOD_MS = 10.0
ESC_TIMEOUT_MS = 100  # the simulator stops the motors after this long without a command


def _truth(log) -> np.ndarray:
    """Rows of sim time [s], north, east [m], ground speed [m/s] from the STATE records."""
    key = vehicle_key(1, "sitl", "state")
    rows = []
    for topic, _message, data in iter_messages(log, key):
        if topic == key:
            r = STATE.decode(data)
            p, v = r["position_ned_m"], r["velocity_ned_mps"]
            rows.append((r["sim_time_us"] / 1e6, p[0], p[1], math.hypot(v[0], v[1])))
    return np.array(sorted(rows))


def _stop(process: subprocess.Popen) -> float:
    """Stop ``process`` for STOP_S; returns how long it stood stopped [s]. Timed under
    SCHED_FIFO where the machine allows it: on the normal scheduler this process, taken
    off its CPU between the two signals, once made a 30 ms stop 1.36 s (the motors stop
    after 0.1 s: the vehicle fell)."""
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(TIMER_PRIORITY))
        raised = True
    except OSError:
        raised = False
    try:
        process.send_signal(signal.SIGSTOP)
        stopped = time.perf_counter()
        while time.perf_counter() - stopped < STOP_S:
            pass
        process.send_signal(signal.SIGCONT)
        return time.perf_counter() - stopped
    finally:
        if raised:
            os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))


def _fly(tmp_path) -> tuple[float, list[tuple[float, float]]]:
    """The flight: the vehicle's time [s] when it was asked to orbit and, for each stop,
    its time just before the stop and how long the autopilot stood stopped [s]."""
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    logger = subprocess.Popen(
        [sys.executable, "-m", "ground.cli", "ground", "log", "--out",
         str(tmp_path / "log"), "--zenoh-listen", endpoint],
        stdout=subprocess.DEVNULL, stderr=subprocess.STDOUT)
    # COM_SIM_LOSS_T 5 s: on a loaded machine the simulator itself may stand still for a
    # second or two (seen in 2 of 30 flights beside a load average of 10); a stalled world
    # is paused, not disturbed, and this flight is about the autopilot's stop, so the
    # link-loss landing is kept out of it.
    procs = start_processes(tmp_path, sim_args=["--zenoh-connect", endpoint],
                            autopilot_args=["--zenoh-connect", endpoint,
                                            "--param", "COM_SIM_LOSS_T=5"])
    tool = GroundTool(procs.gcs_port)
    stops = []
    try:
        tool.connect()
        assert tool.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == 0
        assert tool.command(M.MAV_CMD_NAV_TAKEOFF, *[math.nan] * 7).result == 0
        tool.wait_text("take-off complete", 30)
        # COMMAND_INT: a float latitude (COMMAND_LONG) is 0.4 m coarse here.
        lat, lon, _ = DEFAULT_HOME.geodetic_from_ned(CENTRE_NORTH_M, 0.0, 0.0)
        tool.mav.command_int_send(1, 1, M.MAV_FRAME_GLOBAL, M.MAV_CMD_DO_ORBIT, 0, 0,
                                  RADIUS_M, SPEED_MPS, 0.0, math.nan, round(lat * 1e7),
                                  round(lon * 1e7), DEFAULT_HOME.alt_amsl_m + 3.0)
        ack = tool.wait_type("COMMAND_ACK", 5, lambda m: m.command == M.MAV_CMD_DO_ORBIT)
        assert ack.result == M.MAV_RESULT_ACCEPTED
        # Onto the circle, on the vehicle's clock: within 2 mm/s of the speed 6.4 s after
        # the command (measured), 10 s given; then a stop every 4 s.
        start_ms = tool.wait_type("LOCAL_POSITION_NED").time_boot_ms
        for at_s in STOPS_AT_S:
            before = tool.wait_type("LOCAL_POSITION_NED", 30, lambda m, at_s=at_s:
                                    m.time_boot_ms >= start_ms + 1000 * at_s)
            stops.append((before.time_boot_ms / 1e3, _stop(procs.autopilot)))
        tool.wait_type("LOCAL_POSITION_NED", 30,
                       lambda m: m.time_boot_ms >= start_ms + 1000 * (STOPS_AT_S[-1] + 3))
    finally:
        tool.close()
        procs.stop()
        logger.terminate()
        logger.wait(20)
    return start_ms / 1e3, stops


def _judge(folder: Path, orbit_s: float, stops: list[tuple[float, float]]) -> list[dict]:
    """Each stop as the flight's log shows it: the gap between two control steps it made,
    whether the machine itself disturbed the orbit up to the end of the stop's window
    (then it is not judged), and the speed and radius errors in the 2 s before and after
    it."""
    log = folder / "log"
    truth = _truth(log)
    t, error = truth[:, 0], np.abs(truth[:, 3] - SPEED_MPS)
    radius_error = np.abs(np.hypot(truth[:, 1] - CENTRE_NORTH_M, truth[:, 2]) - RADIUS_M)
    steps_us = control_records(log, 1)["sim_time_us"]
    gaps_us = np.diff(steps_us)
    # The simulator's own stalls of 0.1 s or more (it resumed that far behind the clock).
    resumed_s = [float(t_s) for behind_ms, t_s in re.findall(
        r"(\d+) ms behind the wall clock at t=([\d.]+) s", (folder / "sitl.log").read_text())
        if int(behind_ms) >= ESC_TIMEOUT_MS]
    out = []
    for before_s, stopped_s in stops:
        # The stop in the log: the longest gap between the samples of two control steps
        # from just before the tool's last report (20 Hz: up to 50 ms old) to 0.5 s after.
        near = np.nonzero((steps_us[:-1] >= (before_s - 0.1) * 1e6)
                          & (steps_us[:-1] <= (before_s + 0.5) * 1e6))[0]
        k = near[np.argmax(gaps_us[near])]
        at_s = steps_us[k] / 1e6
        # What the machine did from the orbit's start to the end of the judged window (a
        # disturbed orbit takes seconds to settle).
        around = (steps_us[:-1] >= orbit_s * 1e6) & (
            steps_us[:-1] < (at_s + WINDOW_S) * 1e6)
        after = (t >= at_s) & (t < at_s + WINDOW_S)
        stop = {"stopped_ms": 1e3 * stopped_s, "at_s": float(at_s),
                "gap_ms": float(gaps_us[k]) / 1e3,
                "longest_ms": float(gaps_us[around].max()) / 1e3,
                "resumed_s": [r for r in resumed_s if orbit_s < r < at_s + WINDOW_S],
                "before_mm_s": 1e3 * float(error[(t >= at_s - WINDOW_S) & (t < at_s)].max()),
                "after_mm_s": 1e3 * float(error[after].max()),
                "radius_mm": 1e3 * float(radius_error[after].max())}
        # Not this stop's doing: the simulator late too (the stop shows as fewer than the
        # three periods 30 ms makes), the autopilot standing still as long as the
        # simulator's ESC timeout (the motors stop), the simulator standing still as long.
        stop["judged"] = bool(stop["gap_ms"] >= 3 * PERIOD_MS
                              and stop["longest_ms"] < ESC_TIMEOUT_MS and not stop["resumed_s"])
        out.append(stop)
    return out


def test_a_30_ms_stop_of_the_autopilot_costs_an_orbit_no_speed(tmp_path):
    orbit_s, stops = _fly(tmp_path)
    (tmp_path / "stops.json").write_text(json.dumps([orbit_s, stops]))
    judged = _judge(tmp_path, orbit_s, stops)
    for stop in judged:
        print(json.dumps({k: v if isinstance(v, bool | list) else round(v, 2)
                          for k, v in stop.items()}))
        assert stop["stopped_ms"] >= 1e3 * STOP_S
    judged = [stop for stop in judged if stop["judged"]]
    if not judged:
        # Nothing measured, nothing to judge: say so rather than pass or fail. Seen on the
        # normal scheduler under load (the processes' own stalls of 0.1-0.8 s), and under
        # SCHED_FIFO when the simulator stood still for 1-2 s (2 flights in 30 beside a
        # load average of 10).
        scheduler = ("SCHED_FIFO" if "SCHED_FIFO priority" in
                     (tmp_path / "autopilot.log").read_text() else "the normal scheduler")
        pytest.skip(f"on {scheduler} the machine disturbed the orbit before every stop's "
                    "judged window ended (the autopilot or the simulator standing still "
                    "for 0.1 s or more; the figures above)")
    for stop in judged:
        # Measured, SCHED_FIFO: 0.38-0.70 mm/s after a stop (median 0.64; 42 stops in 14
        # flights, 4 of them beside three CPU-bound processes), 0.38-0.70 before it (the
        # circle's own ripple: in process, without a stop, 0.38-0.79), radius 0.9-2.3 mm;
        # 0.36-0.73 on the normal scheduler (14 stops judged in 8 flights; 3 flights
        # skipped, the processes standing still 0.1-0.8 s by themselves).
        # Before the fixes 28-30 mm/s after every stop; with only the first, 14.6 mm/s
        # after a stop whose next instant flew its sample again.
        assert stop["before_mm_s"] < 3.0  # on the circle, at its speed
        assert stop["after_mm_s"] < 3.0
        assert stop["radius_mm"] < 5.0
