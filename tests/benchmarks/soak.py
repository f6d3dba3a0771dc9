"""Real-time soak: logger + simulator + autopilot at 250 Hz for an hour (attitude-sine
reference), sampled every minute.

Each minute it prints the autopilot's deadline misses, jitter p50/p99/max and compute
p99 over that minute (from the autopilot's timing records, read over Zenoh like any
subscriber) and the resident memory of each process; at the end, each process's RSS
against its value after the first minute.

    python tests/benchmarks/soak.py                      # 60 minutes at 250 Hz
    python tests/benchmarks/soak.py --minutes 10 --rate-hz 100 --json soak.json

Loopback only; bounded by --minutes; asserts nothing.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from contracts.realtime import Histogram  # noqa: E402
from contracts.telemetry import AUTOPILOT, TIMING, vehicle_key  # noqa: E402
from contracts.zenoh_link import ZenohOptions, open_session  # noqa: E402
from ground.processes import LoggerProcess, free_tcp_port  # noqa: E402


def rss_mib(pid: int) -> float:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    return float("nan")


class MinuteTiming:
    """Jitter, compute and misses of the timing records received this minute."""

    def __init__(self, period_s: float) -> None:
        self.period_s = period_s
        self.lock = threading.Lock()
        self.misses_seen = 0
        self.records = 0
        self._fresh()

    def _fresh(self) -> None:
        self.jitter, self.compute = Histogram(), Histogram()
        self.misses_at_start = self.misses_seen

    def on_sample(self, sample) -> None:
        r = TIMING.decode(sample.payload.to_bytes())
        with self.lock:
            self.records += 1
            self.misses_seen = int(r["deadline_misses"])
            self.compute.add(float(r["compute_s"]))
            if r["period_s"] == r["period_s"]:  # NaN after a restart of the loop
                self.jitter.add(abs(float(r["period_s"]) - self.period_s))

    def take(self) -> dict:
        with self.lock:
            j, c = self.jitter, self.compute
            out = {"steps": c.n, "misses": self.misses_seen - self.misses_at_start,
                   "jitter_p50_ms": j.percentile(50) * 1e3,
                   "jitter_p99_ms": j.percentile(99) * 1e3, "jitter_max_ms": j.max_s * 1e3,
                   "compute_p99_ms": c.percentile(99) * 1e3}
            self._fresh()
        return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--minutes", type=float, default=60.0)
    parser.add_argument("--rate-hz", type=float, default=250.0)
    parser.add_argument("--json", type=Path, help="also write the per-minute rows here")
    parser.add_argument("--keep", type=Path, help="run folder to keep (default: temporary)")
    args = parser.parse_args()
    duration_s = args.minutes * 60.0
    with tempfile.TemporaryDirectory() as tmp:
        out = args.keep or Path(tmp)
        out.mkdir(parents=True, exist_ok=True)
        endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
        sim_port = free_tcp_port()
        logger = LoggerProcess(out, endpoint, out / "logger.txt")
        zenoh_args = ["--zenoh-connect", endpoint]
        logs = {name: open(out / f"{name}.txt", "w") for name in ("sitl", "autopilot")}  # noqa: SIM115
        procs = {"logger": logger.proc}
        procs["sitl"] = subprocess.Popen(
            [sys.executable, "-m", "sitl", "--port", str(sim_port), "--realtime",
             "--rate-hz", str(args.rate_hz), "--start-altitude", "1.0",
             "--exit-on-disconnect", *zenoh_args], stdout=logs["sitl"], stderr=subprocess.STDOUT)
        procs["autopilot"] = subprocess.Popen(
            [sys.executable, "-m", "autopilot", "--sim", f"127.0.0.1:{sim_port}", "--realtime",
             "--rate-hz", str(args.rate_hz), "--reference", "attitude-sine",
             "--arm-in-reference", "--duration", str(duration_s + 5.0), "--gcs-bind", "0",
             "--api", "none", "--api-bind", "0", *zenoh_args],
            stdout=logs["autopilot"], stderr=subprocess.STDOUT)
        timing = MinuteTiming(1.0 / args.rate_hz)
        session = open_session(ZenohOptions(mode="peer", connect=[endpoint], listen=[]))
        sub = session.declare_subscriber(vehicle_key(1, AUTOPILOT, "timing"), timing.on_sample)
        rows = []
        try:
            start = time.monotonic()
            while timing.records == 0 and time.monotonic() - start < 120.0:
                time.sleep(0.1)  # the loop is running
            start = time.monotonic()
            timing.take()
            minute = 0
            while minute < args.minutes and procs["autopilot"].poll() is None:
                time.sleep(max(0.0, start + 60.0 * (minute + 1) - time.monotonic()))
                minute += 1
                row = {"minute": minute, **timing.take(),
                       **{f"rss_{n}_mib": round(rss_mib(p.pid), 1) for n, p in procs.items()}}
                rows.append(row)
                print(f"min {minute:3d}  steps {row['steps']:6d}  misses {row['misses']:3d}  "
                      f"jitter p50/p99/max {row['jitter_p50_ms']:.3f}/{row['jitter_p99_ms']:.3f}/"
                      f"{row['jitter_max_ms']:.3f} ms  compute p99 {row['compute_p99_ms']:.3f} ms"
                      f"  RSS MiB " + " ".join(f"{n} {row[f'rss_{n}_mib']:.1f}" for n in procs),
                      flush=True)
        finally:
            sub.undeclare()
            session.close()
            for name in ("autopilot", "sitl"):
                if procs[name].poll() is None:
                    procs[name].terminate()
                    procs[name].wait(timeout=30.0)
                logs[name].close()
            logger.stop()
        if rows:
            first = rows[0]
            print("RSS change from the first minute to the last: " + ", ".join(
                f"{n} {100 * (rows[-1][f'rss_{n}_mib'] / first[f'rss_{n}_mib'] - 1):+.1f} % "
                f"(max {100 * (max(r[f'rss_{n}_mib'] for r in rows) / first[f'rss_{n}_mib'] - 1):+.1f} %)"  # noqa: E501
                for n in procs))
            print(f"total misses {sum(r['misses'] for r in rows)}, worst minute p99 "
                  f"{max(r['jitter_p99_ms'] for r in rows):.3f} ms")
        if args.json:
            args.json.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
