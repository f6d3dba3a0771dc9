"""The ground logger under load: sustained records per second with zero loss, and its CPU.

    python tests/benchmarks/bench_logger.py [--vehicles 10] [--rate-hz 1000] [--seconds 10]

Load processes (two, one per core) each play several vehicles: one Zenoh session per
vehicle, publishing the autopilot's real control record (``contracts.telemetry.CONTROL``
with the shipped model's theta_f sizes, ~1 kB) at the rate given, paced on the wall
clock, then the final status with their counts. The logger is the real ``ivfm ground log``
process; its CPU time comes from /proc. Loss = published - logged, per key, and the
sequence numbers in the MCAP file are checked for holes. Prints figures; asserts nothing.
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

import numpy as np  # noqa: E402

from contracts.telemetry import CONTROL, vehicle_key  # noqa: E402
from contracts.zenoh_link import ZenohOptions, open_session  # noqa: E402
from ground.record.run_files import iter_messages  # noqa: E402
from ground.run.children import LoggerProcess  # noqa: E402

LOAD = """
import sys, time, json
sys.path.insert(0, {root!r})
import numpy as np
from contracts.telemetry import CONTROL
from contracts.telemetry_node import TelemetryNode
from contracts.zenoh_link import ZenohOptions
vehicles, rate_hz, seconds, endpoint = json.loads(sys.argv[1])
opts = ZenohOptions(listen=["tcp/127.0.0.1:0"], connect=[endpoint])
nodes = [TelemetryNode(opts, v, "autopilot", log=lambda t: None) for v in vehicles]
pubs = [n.publisher("control") for n in nodes]
deadline = time.monotonic() + 30
while not all(p.matched for p in pubs) and time.monotonic() < deadline:
    time.sleep(0.05)
for n in nodes:
    n.status(0, force=True)
time.sleep(1.0)
rng = np.random.default_rng(0)
record = CONTROL.buffer()
for name in ('measurement', 'reference', 'motor_commands', 'theta_g'):
    record[name] = rng.normal(size=record[name].shape)
record['mode'], record['flags'] = 4, 1
tails = tuple(rng.normal(size=k) for k in (24, 24, 12))
period = 1.0 / rate_hz
start = time.perf_counter()
steps = int(seconds * rate_hz)
for k in range(steps):
    while time.perf_counter() < start + k * period:
        pass
    t_us = int(k * period * 1e6)
    for p in pubs:
        record['seq'], record['sim_time_us'] = p.count, t_us
        p.put(record.encode(tails))
print(json.dumps({{"late_s": time.perf_counter() - start - seconds}}), flush=True)
for n in nodes:
    n.status(t_us, final=True)
time.sleep(0.5)
for n in nodes:
    n.close()
"""


def cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--vehicles", type=int, default=10)
    parser.add_argument("--rate-hz", type=float, default=1000.0)
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--load-processes", type=int, default=2)
    args = parser.parse_args()
    root = str(Path(__file__).resolve().parents[2])
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        endpoint = f"tcp/127.0.0.1:{s.getsockname()[1]}"
    ids = list(range(1, args.vehicles + 1))
    groups = [ids[i::args.load_processes] for i in range(args.load_processes)]
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        logger = LoggerProcess(tmp / "log", endpoint, tmp / "logger.log")
        session = open_session(ZenohOptions(listen=["tcp/127.0.0.1:0"], connect=[endpoint]))
        loads = [subprocess.Popen([sys.executable, "-c", LOAD.format(root=root),
                                   json.dumps([g, args.rate_hz, args.seconds, endpoint])],
                                  stdout=subprocess.PIPE, text=True) for g in groups]
        status_keys = [vehicle_key(v, "autopilot", "status") for v in ids]
        logger.wait_until(session, status_keys, final=False, timeout_s=60)
        cpu0, wall0 = cpu_seconds(logger.proc.pid), time.monotonic()
        late = [json.loads(p.stdout.readline())["late_s"] for p in loads]
        status = logger.wait_until(session, status_keys, final=True, timeout_s=60)
        cpu1, wall1 = cpu_seconds(logger.proc.pid), time.monotonic()
        for p in loads:
            p.wait()
        session.close()
        logger.stop()
        published = sum(status["heard"][k]["published"][vehicle_key(int(k.split("/")[2]),
                                                                     "autopilot", "control")]
                        for k in status_keys)
        logged = sum(status["per_key"].get(vehicle_key(v, "autopilot", "control"), 0)
                     for v in ids)
        holes = 0
        size = sum(f.stat().st_size for f in (tmp / "log").glob("*.mcap"))
        seqs: dict[str, list[int]] = {}
        for topic, _m, data in iter_messages(tmp / "log", "ivfm/vehicle/"):
            if topic.endswith("/control"):
                seqs.setdefault(topic, []).append(int(CONTROL.decode(data)["seq"]))
        in_file = sum(len(v) for v in seqs.values())
        for v in seqs.values():
            holes += len(np.setdiff1d(np.arange(max(v) + 1), v))
    offered = args.vehicles * args.rate_hz
    print(f"{args.vehicles} vehicles x {args.rate_hz:g} Hz control records "
          f"({offered:.0f} records/s offered for {args.seconds:g} s; the publishers ran "
          f"{max(late) * 1e3:.0f} ms late in total)")
    print(f"published {published}, logged {logged}, in the MCAP file {in_file}, lost "
          f"{published - in_file}, sequence holes {holes}")
    print(f"logger CPU {cpu1 - cpu0:.2f} s over {wall1 - wall0:.2f} s wall: "
          f"{100 * (cpu1 - cpu0) / (wall1 - wall0):.0f} % of one core; "
          f"{in_file / (wall1 - wall0):.0f} records/s sustained; file {size / 1e6:.1f} MB")


if __name__ == "__main__":
    main()
