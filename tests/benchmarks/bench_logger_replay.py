"""The logger's CPU per simulated second of a real flight, records one by one (as before
batches) against batches, in the same run.

    python tests/benchmarks/bench_logger_replay.py                 # this checkout's logger
    python tests/benchmarks/bench_logger_replay.py --before /path/to/older/checkout
    python tests/benchmarks/bench_logger_replay.py --rounds 5

A 60 s lockstep attitude-sine is flown once through the processes; its records (the
simulator's state, the autopilot's control and timing, the MAVLink mirror) are then
played again to a real ``ivfm ground log`` process, paced at --speed times real time as
a lockstep run sends them: once with one put per record, once in batches of lockstep's
span of sim time (100 ms, contracts/telemetry.py pack_batch). ``--before`` also plays
the records one by one to the logger of another checkout (one that predates batches).
The logger's CPU (every thread) comes from /proc between the first record and its last.
The plays go in turn, --rounds times, and the ratio of batches to the first play is
given per round: the machine's speed drifts between runs (docs/developing.md).
Prints figures; asserts nothing.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from contracts.telemetry import (  # noqa: E402
    MIRROR_ATTACHMENT,
    json_record,
    pack_batch,
    parse_key,
    vehicle_key,
)
from contracts.zenoh_link import LOCKSTEP_BATCH_S, ZenohOptions, open_session  # noqa: E402
from ground.record.run_files import iter_messages  # noqa: E402
from ground.run.processes import RunSettings, run_processes  # noqa: E402
from ground.scenario.scenario_file import scenario_by_name  # noqa: E402

Record = tuple[int, str, bytes, bytes | None]  # sim time, key, payload, attachment


def flight_records(duration_s: float, out: Path) -> list[Record]:
    """The records of a lockstep flight, in the order of their sim time."""
    scenario = dataclasses.replace(scenario_by_name("attitude-sine"), duration_s=duration_s)
    run_processes(scenario, RunSettings("ivfc", "paper", "paper"), out, quiet=True)
    records = []
    for topic, message, data in iter_messages(out, ""):
        parsed = parse_key(topic)
        if topic.startswith("mavlink/"):
            attachment = MIRROR_ATTACHMENT.pack(message.sequence, message.publish_time // 1000)
        elif parsed is not None and parsed[2] in ("state", "control", "timing"):
            attachment = None
        else:
            continue
        records.append((message.publish_time // 1000, topic, data, attachment))
    records.sort(key=lambda r: r[0])
    return records


def cpu_seconds(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def start_logger(root: Path, out: str, name: str, endpoint: str) -> subprocess.Popen:
    """``ivfm ground log`` of the checkout at ``root``, listening on ``endpoint``."""
    return subprocess.Popen(
        [sys.executable, "-m", "ground.cli", "ground", "log", "--out", out, "--name", name,
         "--zenoh-listen", endpoint], cwd=root, env={**os.environ, "PYTHONPATH": str(root)},
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def play(records: list[Record], root: Path, batched: bool, speed: float,
         span_us: int = round(1e6 * LOCKSTEP_BATCH_S)) -> float:
    """The logger's CPU seconds for ``records`` played at ``speed`` x real time, in
    batches of ``span_us`` of sim time when ``batched``."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    with tempfile.TemporaryDirectory() as tmp:
        logger = start_logger(root, tmp, "b", endpoint)
        session = open_session(ZenohOptions(connect=[endpoint]))
        try:
            probe = session.declare_publisher(vehicle_key(1, "sitl", "status"))
            while not probe.matching_status.matching:
                time.sleep(0.02)
            time.sleep(0.5)
            cpu0 = cpu_seconds(logger.pid)
            start = time.perf_counter()
            pending: dict[str, list] = {}
            due_us = span_us
            for t_us, key, payload, attachment in records:
                while time.perf_counter() < start + t_us / 1e6 / speed:
                    pass
                if not batched:
                    session.put(key, payload, attachment=attachment)
                    continue
                if t_us >= due_us:
                    _send_batches(session, pending)
                    due_us = t_us - t_us % span_us + span_us
                process = "sitl" if key.endswith("/state") else "autopilot"
                pending.setdefault(process, []).append((key, payload, attachment))
            _send_batches(session, pending)
            session.put(vehicle_key(1, "sitl", "status"), json_record(0, 0, final=True))
            time.sleep(1.0)  # the logger drains its inbox (its CPU is counted to here)
            return cpu_seconds(logger.pid) - cpu0
        finally:
            session.close()
            logger.terminate()
            logger.wait(20)


def _send_batches(session, pending: dict[str, list]) -> None:
    for process, entries in pending.items():
        if not entries:
            continue
        keys = list(dict.fromkeys(k for k, _, _ in entries))
        session.put(vehicle_key(1, process, "batch"), pack_batch(
            keys, [keys.index(k) for k, _, _ in entries], [p for _, p, _ in entries],
            [a or b"" for _, _, a in entries]))
        entries.clear()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=60.0, help="sim seconds")
    parser.add_argument("--speed", type=float, default=20.0, help="x real time")
    parser.add_argument("--before", type=Path, help="another checkout's root")
    parser.add_argument("--rounds", type=int, default=3,
                        help="rounds, each playing every variant once, in turn (the "
                             "machine's speed drifts: compare within a round)")
    args = parser.parse_args()
    here = Path(__file__).resolve().parents[2]
    with tempfile.TemporaryDirectory() as tmp:
        records = flight_records(args.duration, Path(tmp))
    print(f"{len(records)} records of a {args.duration:g} s flight, played at "
          f"{args.speed:g}x real time")
    plays = [("this logger, one put per record", here, False),
             (f"this logger, batches of {1e3 * LOCKSTEP_BATCH_S:g} ms (lockstep's)", here,
              True)]
    if args.before is not None:
        plays.insert(0, (f"{args.before}'s logger, one put per record", args.before, False))
    ratios = []
    for k in range(args.rounds):
        print(f"round {k + 1}:")
        figures = []
        for name, root, batched in plays:
            cpu_s = play(records, root, batched, args.speed)
            figures.append(cpu_s)
            print(f"  {name}: {1e3 * cpu_s / args.duration:.1f} ms of CPU per sim second "
                  f"({1e6 * cpu_s / (args.duration * 100):.0f} us per 10 ms cycle)",
                  flush=True)
        ratios.append(figures[-1] / figures[0])
    print(f"batches against {plays[0][0]}: " + ", ".join(f"{r:.2f}" for r in ratios)
          + f" (median {statistics.median(ratios):.2f})")

if __name__ == "__main__":
    main()
