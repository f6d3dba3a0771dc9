"""The logger's resident memory over an hour's records at 250 Hz, in minutes, and what a
backlog leaves behind (docs/realtime.md, "The logger's memory").

    python tests/benchmarks/bench_logger_memory.py                     # 3.7 M records
    python tests/benchmarks/bench_logger_memory.py --starve 0.3:15     # a backlog at 30 %
    python tests/benchmarks/bench_logger_memory.py --root /other/checkout --starve 0.3:15

A 60 s lockstep attitude-sine is flown once through the processes; its records (the
simulator's state, the autopilot's control and timing, the MAVLink mirror) are then
played again and again, sim time scaled to 250 Hz and each lap's seq and sim time carried
on, in batches per 20 ms of sim time as the vehicles send them, to a real ``ivfm ground
log`` process (of this checkout or ``--root``'s). The logger's work depends on the records,
not the clock, so the hour's 3.7 M records go at ``--speed`` x real time, held back
whenever the logger is more than ``--max-behind`` records behind (its status reply counts
what it wrote): what is measured is the logger keeping up, as at 250 Hz, not an
overloaded one. ``--starve FRACTION:SECONDS`` starves its loop at that point of the
stream: its main thread at nice 19 on one CPU beside two CPU-bound processes, Zenoh's
threads untouched, records coming on, as a soak's logger is when neighbours take its CPU.

Prints the logger's RSS (/proc/PID/status) every 5 % of the records, and the growth
from 10 % to the end. Prints figures; asserts nothing.
"""

from __future__ import annotations

import argparse
import json
import os
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_logger_replay import (  # noqa: E402
    Record,
    flight_records,
    free_port,
    start_logger,
)

from contracts.telemetry import (  # noqa: E402
    MIRROR_ATTACHMENT,
    json_record,
    logger_key,
    pack_batch,
    vehicle_key,
)
from contracts.zenoh_link import ZenohOptions, open_session  # noqa: E402

SPAN_US = 20_000  # a batch per 20 ms of sim time, per process, as the vehicles send
RATE_SCALE = 0.4  # the 100 Hz flight's sim time, as 250 Hz
HOG = "while True: pass"


def rss_mib(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


class Stream:
    """The flight's records lap after lap, at 250 Hz of sim time, seq and sim time going on."""

    def __init__(self, records: list[Record]) -> None:
        self.records = [(int(t_us * RATE_SCALE), key, payload, attachment)
                        for t_us, key, payload, attachment in records]
        self.lap_us = self.records[-1][0] + int(10_000 * RATE_SCALE)
        self.seq: dict[str, int] = {}

    def __iter__(self):
        lap = 0
        while True:
            for t_us, key, payload, attachment in self.records:
                t_us += lap * self.lap_us
                seq = self.seq.get(key, 0)
                self.seq[key] = seq + 1
                if attachment is not None:  # a mirror frame: seq and sim time attached
                    yield t_us, key, payload, MIRROR_ATTACHMENT.pack(seq, t_us)
                else:  # a CDR record: seq and sim time after the CDR header
                    record = bytearray(payload)
                    struct.pack_into("<Qq", record, 4, seq, t_us)
                    yield t_us, key, bytes(record), None
            lap += 1


def play(records: list[Record], root: Path, args: argparse.Namespace) -> list[float]:
    """The logger's RSS [MiB] at every 5 % of ``args.records`` records."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    starve_at, starve_s = args.starve or (2.0, 0.0)
    with tempfile.TemporaryDirectory() as tmp:
        logger = start_logger(root, tmp, "mem", endpoint)
        session = open_session(ZenohOptions(connect=[endpoint]))
        publishers: dict[str, object] = {}
        hogs: list[subprocess.Popen] = []

        def put(key: str, payload: bytes) -> None:
            if key not in publishers:
                publishers[key] = session.declare_publisher(key)
            publishers[key].put(payload)

        def written() -> int | None:
            for reply in session.get(logger_key("mem", "status"), timeout=5.0):
                if reply.ok is not None:
                    return json.loads(reply.ok.payload.to_bytes())["records"]
            return None

        pending: dict[str, list] = {"sitl": [], "autopilot": []}

        def send() -> None:
            for process, entries in pending.items():
                if entries:
                    keys = list(dict.fromkeys(k for k, _, _ in entries))
                    put(vehicle_key(1, process, "batch"), pack_batch(
                        keys, [keys.index(k) for k, _, _ in entries],
                        [p for _, p, _ in entries], [a or b"" for _, _, a in entries]))
                    entries.clear()

        try:
            while written() is None:
                time.sleep(0.1)
            time.sleep(0.5)
            rss = []
            start, waited_s, due_us, starve_end = time.perf_counter(), 0.0, SPAN_US, None
            for n, (t_us, key, payload, attachment) in enumerate(Stream(records), 1):
                while time.perf_counter() < start + waited_s + t_us / 1e6 / args.speed:
                    pass
                if t_us >= due_us:
                    send()
                    due_us = t_us - t_us % SPAN_US + SPAN_US
                pending["sitl" if "/sitl/" in key else "autopilot"].append(
                    (key, payload, attachment))
                if n == int(starve_at * args.records):
                    cpu = os.cpu_count() - 1
                    before = rss_mib(logger.pid)
                    os.sched_setaffinity(logger.pid, [cpu])  # the main thread (the loop)
                    os.setpriority(os.PRIO_PROCESS, logger.pid, 19)
                    hogs = [subprocess.Popen(["taskset", "-c", str(cpu), sys.executable,
                                              "-c", HOG]) for _ in range(2)]
                    starve_end = time.perf_counter() + starve_s
                if starve_end is not None and time.perf_counter() >= starve_end:
                    for hog in hogs:
                        hog.kill()
                        hog.wait()
                    hogs, starve_end = [], None
                    os.sched_setaffinity(logger.pid, range(os.cpu_count()))
                    print(f"  starved {starve_s:g} s at {starve_at:.0%}: RSS {before:.1f} -> "
                          f"{rss_mib(logger.pid):.1f} MiB", flush=True)
                if n % 2000 == 0 and starve_end is None:  # keep up, as at 250 Hz
                    send()
                    t0 = time.perf_counter()
                    while (done := written()) is None or n - done > args.max_behind:
                        time.sleep(0.02)
                    waited_s += time.perf_counter() - t0
                if n % (args.records // 20) == 0:
                    rss.append(rss_mib(logger.pid))
                    print(f"  {n / args.records:4.0%} {n:9d} records  RSS {rss[-1]:6.1f} MiB",
                          flush=True)
                if n >= args.records:
                    break
            send()
            put(vehicle_key(1, "sitl", "status"), json_record(0, 0, final=True))
            last = None
            while (done := written()) is None or done != last:  # all in (some may be lost)
                last = done
                time.sleep(1.0)
            print(f"  the logger wrote {done - 1} of {args.records} records", flush=True)
            return rss
        finally:
            for hog in hogs:
                hog.kill()
                hog.wait()
            session.close()
            logger.terminate()
            logger.wait(60)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--records", type=int, default=3_700_000,
                        help="records played (an hour at 250 Hz: 3.7 M)")
    parser.add_argument("--speed", type=float, default=10.0, help="x real time, at most")
    parser.add_argument("--max-behind", type=int, default=10_000,
                        help="hold back while the logger is this many records behind")
    parser.add_argument("--starve", type=lambda text: tuple(map(float, text.split(":"))),
                        metavar="FRACTION:SECONDS", help="starve the logger's loop then")
    parser.add_argument("--root", type=Path, default=Path(__file__).resolve().parents[2],
                        help="the checkout whose logger runs")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        records = flight_records(60.0, Path(tmp))
    print(f"{args.records} records (a lap of {len(records)}) to {args.root}'s logger, "
          f"at most {args.speed:g}x real time", flush=True)
    rss = play(records, args.root, args)
    print(f"RSS at 10 % {rss[1]:.1f} MiB, at the end {rss[-1]:.1f} MiB: "
          f"{100 * (rss[-1] / rss[1] - 1):+.1f} % (max {max(rss):.1f} MiB)")


if __name__ == "__main__":
    main()
