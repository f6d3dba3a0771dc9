"""Benchmarks of the SITL processes (logger + simulator + autopilot): lockstep real-time
factor and one cycle's parts (the simulator link's codec as the processes run it: its
compiled code, contracts/sim_samples.py and contracts/sim_readings.py; pymavlink's codec in
the same parts beside them).

    python tests/benchmarks/bench_processes.py            # lockstep figures
    python tests/benchmarks/bench_processes.py --realtime # 60 s real-time jitter, 100/250 Hz

Prints figures; asserts nothing (speed is measured here, not in timed tests).
"""

from __future__ import annotations

import argparse
import dataclasses
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

import numpy as np  # noqa: E402

from autopilot.commander.commander import Commander  # noqa: E402
from autopilot.control.factory import load_models, make_controller  # noqa: E402
from autopilot.trajectories import Reference  # noqa: E402
from contracts.airframe import PAPER, hover_rotor_speeds  # noqa: E402
from contracts.frames import DEFAULT_HOME  # noqa: E402
from contracts.mavlink import (  # noqa: E402
    actuator_message,
    commands_from_actuator,
    mavlink,
    measurement_from_odometry,
    split_frames,
)
from contracts.sim_readings import MAX_FRAMES, VALUES, read_frames  # noqa: E402
from contracts.sim_samples import (  # noqa: E402
    ACTUATORS_BYTES,
    FIX_SIZE,
    SAMPLE_BYTES,
    pack_actuators,
    pack_sample,
    sample_messages,  # noqa: E402
    sensor_reading,
)
from ground.run.processes import RunSettings, fly  # noqa: E402
from ground.scenario.scenario_file import scenario_by_name  # noqa: E402
from sitl.plant import Plant
from sitl.truth import ideal_readings  # noqa: E402

ECHO = """
import socket, sys
srv = socket.create_server(("127.0.0.1", 0)); print(srv.getsockname()[1], flush=True)
conn, _ = srv.accept(); conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
n = int(sys.argv[1])
while True:
    data = conn.recv(65536)
    if not data: break
    conn.sendall(b"x" * n)
"""


def _per_call_us(fn, n: int = 3000) -> float:
    fn()
    best = []
    for _ in range(3):
        start = time.perf_counter()
        for _ in range(n):
            fn()
        best.append((time.perf_counter() - start) / n * 1e6)
    return min(best)


def cycle_parts() -> tuple[dict[str, float], dict[str, float]]:
    """(the cycle's parts as the processes run them, pymavlink's codec in the same parts
    for comparison) in microseconds per call."""
    models = load_models(None)
    plant = Plant(PAPER, "paper", 0.001, position_ned_m=(0, 0, -1),
                  rotor_rad_s=hover_rotor_speeds(PAPER), ground_contact=True)
    vehicle = Commander(lambda p: make_controller("ivfc", PAPER, 0.01, models, p), 0.01,
                      reference=Reference("attitude-sine"))
    vehicle.sample(0.0, plant.true_measurement())
    vehicle.arm_in_reference()
    sim_mav = mavlink.MAVLink(None, 1, 51)
    ap_mav = mavlink.MAVLink(None, 1, 1)
    s = plant.state()

    out = np.empty(max(SAMPLE_BYTES, ACTUATORS_BYTES), dtype=np.uint8)
    table, values = np.zeros((MAX_FRAMES, 4), dtype=np.int64), np.zeros((MAX_FRAMES, VALUES))
    home = np.array(DEFAULT_HOME)
    truth, sensor, _fix = ideal_readings(0, s, np.zeros(3))
    reading, no_fix, accel = sensor_reading(sensor), np.zeros(FIX_SIZE), np.zeros(3)
    numbers = s.numbers()

    def encode_sample(pymavlink: bool = False) -> bytes:
        if pymavlink:
            msgs = sample_messages(*ideal_readings(0, s, np.zeros(3)), DEFAULT_HOME)
            return b"".join(m.pack(sim_mav) for m in msgs)
        end, _, _ = pack_sample(out, sim_mav.seq, 1, 51, home, 0, numbers, accel, reading,
                                no_fix, -1)
        return out[:end].tobytes()

    sample = encode_sample()
    odometry_id = mavlink.MAVLINK_MSG_ID_ODOMETRY
    wanted = np.array([odometry_id], dtype=np.int64)

    def decode_sample(pymavlink: bool = False) -> None:
        # As the autopilot's SimLink: only the state message is read.
        if pymavlink:
            frames, _ = split_frames(sample)
            msgs = ap_mav.parse_buffer(b"".join(f for i, f in frames if i == odometry_id))
            for msg in msgs:
                measurement_from_odometry(msg)
        else:
            read_frames(np.frombuffer(sample, dtype=np.uint8), wanted, home, table, values)

    def encode_actuator(pymavlink: bool = False) -> bytes:
        if pymavlink:
            return actuator_message(0, np.full(4, 0.5), True, True).pack(ap_mav)
        end = pack_actuators(out, 0, 1, 1, 0, np.full(4, 0.5), 128, 1)
        return out[:end].tobytes()

    actuator = encode_actuator()
    every = np.zeros(0, dtype=np.int64)

    def decode_actuator(pymavlink: bool = False) -> None:
        if pymavlink:
            for msg in sim_mav.parse_buffer(actuator):
                commands_from_actuator(msg)
        else:
            read_frames(np.frombuffer(actuator, dtype=np.uint8), every, home, table, values)

    parts = {
        "sim: state -> 4 messages (encode)": _per_call_us(encode_sample),
        "autopilot: 4 messages -> measurement (decode)": _per_call_us(decode_sample),
        "autopilot: control step (IVFC + vehicle logic)": _per_call_us(
            lambda: vehicle.step(0.0, plant.true_measurement())),
        "autopilot: actuator message (encode)": _per_call_us(encode_actuator),
        "sim: actuator message (decode)": _per_call_us(decode_actuator),
        "sim: plant 10 ms (10 RK4 steps) + state": _per_call_us(
            lambda: (plant.advance(0.01), plant.state())),
    }
    pymavlink = {name: _per_call_us(lambda fn=fn: fn(True)) for name, fn in (
        ("sim: state -> 4 messages (encode)", encode_sample),
        ("autopilot: 4 messages -> measurement (decode)", decode_sample),
        ("autopilot: actuator message (encode)", encode_actuator),
        ("sim: actuator message (decode)", decode_actuator))}
    # Transport: the same bytes ping-ponged with a second process over TCP loopback.
    echo = subprocess.Popen([sys.executable, "-c", ECHO, str(len(actuator))],
                            stdout=subprocess.PIPE, text=True)
    port = int(echo.stdout.readline())
    conn = socket.create_connection(("127.0.0.1", port))
    conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)

    def round_trip():
        conn.sendall(sample)
        got = 0
        while got < len(actuator):
            got += len(conn.recv(65536))

    parts["send + receive both ways (TCP loopback, 2 processes)"] = _per_call_us(round_trip,
                                                                                2000)
    conn.close()
    echo.wait(5)
    return parts, pymavlink


PAPER_IVFC = RunSettings("ivfc", "paper", "paper")


def lockstep_rtf(settings: RunSettings = PAPER_IVFC, repeats: int = 3) -> list[float]:
    scenario = dataclasses.replace(scenario_by_name("attitude-sine"), duration_s=60.0)
    out = []
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(repeats):
            record, _ = fly(scenario, settings, Path(tmp) / str(i))
            out.append(scenario.duration_s / record.wall_time_s)
    return out


def realtime(rate_hz: float, duration_s: float = 60.0) -> dict:
    scenario = dataclasses.replace(scenario_by_name("attitude-sine"), duration_s=duration_s)
    with tempfile.TemporaryDirectory() as tmp:
        _, accounting = fly(scenario, RunSettings("ivfc", "paper", "paper", realtime=True,
                                                  rate_hz=rate_hz), Path(tmp))
    return accounting["timing"]


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--realtime", action="store_true")
    args = parser.parse_args()
    if args.realtime:
        for rate in (100.0, 250.0):
            t = realtime(rate)
            print(f"real time {rate:g} Hz, 60 s: jitter p50 {t['jitter_p50_ms']:.3f} ms, "
                  f"p99 {t['jitter_p99_ms']:.3f} ms, max {t['jitter_max_ms']:.3f} ms; "
                  f"compute p50 {t['compute_p50_ms']:.3f} ms, p99 {t['compute_p99_ms']:.3f} "
                  f"ms; deadline misses {t['deadline_misses']} of {t['steps']} steps")
        return
    parts, pymavlink = cycle_parts()
    print("one lockstep cycle, by part (us, best of 3; pymavlink's codec in brackets):")
    for name, us in parts.items():
        before = f"({pymavlink[name]:6.1f})" if name in pymavlink else " " * 8
        print(f"  {us:8.1f} {before}  {name}")
    total = sum(parts.values())
    print(f"  {total:8.1f}           sum -> at most {1e4 / total:.0f}x real time at 100 Hz")
    rtf = lockstep_rtf()
    print(f"lockstep attitude-sine, 60 s sim, both processes and all messages: "
          f"{statistics.median(rtf):.0f}x real time (runs: "
          f"{', '.join(f'{r:.0f}x' for r in rtf)}; control loop only, process start "
          f"excluded)")
    # The onboard estimator's cost: the same flight on the rigid body, on truth and on the
    # estimator fed by the typical sensors.
    truth = statistics.median(lockstep_rtf(RunSettings("ivfc", "rigid-body", "paper")))
    estimator = statistics.median(lockstep_rtf(RunSettings(
        "ivfc", "rigid-body", "paper", state_source="estimator", sensors="typical")))
    print(f"lockstep attitude-sine on the rigid body, 60 s sim: on truth {truth:.1f}x real "
          f"time, on the estimator (typical sensors) {estimator:.1f}x: "
          f"{100 * (truth / estimator - 1):.0f} % slower")


if __name__ == "__main__":
    main()
