"""Real-time soak: logger + simulator + autopilot at 250 Hz for an hour, as a vehicle is
flown: a ground tool (pymavlink) sends heartbeats, streams hover setpoints in OFFBOARD and
changes a parameter every minute, a wind perturbation comes every minute over Zenoh, and
CPU-bound neighbours (``ivfm run attitude-sine --inprocess`` in a loop) may run beside it.

Each minute it prints the autopilot's deadline misses, jitter p50/p99/max and compute
p99 over that minute (from the autopilot's timing records, read over Zenoh like any
subscriber), beside them the periods a reference sleeper lost in the same minute and its
worst wake-up (cyclictest when installed, else the built-in one, at the autopilot's period,
priority and CPUs: ground/run/reference.py; the machine's own misses), and each process's
resident memory, open files and threads; at the end, both totals, RSS against its value
after the first minute and published against logged records.

    python tests/benchmarks/soak.py                      # 60 minutes at 250 Hz, alone
    python tests/benchmarks/soak.py --neighbours 2 --rt-cpus 0 --shield
    python tests/benchmarks/soak.py --minutes 10 --rate-hz 100 --json soak.json
    python tests/benchmarks/soak.py --minutes 3 --reference built-in   # or none

``--shield`` runs ``ivfm shield`` on the --rt-cpus list for the soak (root) and lifts it
afterwards. Loopback only; bounded by --minutes; asserts nothing.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from contracts.arguments import AUTOPILOT_RT_PRIORITY, cpu_list  # noqa: E402
from contracts.mavlink import mavlink  # noqa: E402
from contracts.realtime import Histogram, shield_cpus  # noqa: E402
from contracts.telemetry import (  # noqa: E402
    AUTOPILOT,
    BATCH_TOPIC,
    SITL,
    TIMING,
    unbatched,
    vehicle_key,
)
from contracts.zenoh_link import ZenohOptions, open_session  # noqa: E402
from ground.run.children import LoggerProcess, free_tcp_port, free_udp_port  # noqa: E402
from ground.run.processes import telemetry_accounting  # noqa: E402
from ground.run.reference import CHOICES, ReferenceSleeper, ReferenceTally, summary  # noqa: E402
from ground.scenario.ground_station import GroundStation, GroundStationPlan  # noqa: E402
from ground.uplink.perturb import PerturbationClient  # noqa: E402

NEIGHBOUR = ("while true; do {nice}ivfm run attitude-sine --inprocess "
             "--out {out} >/dev/null 2>&1; done")
PARAM = b"MPC_XY_VEL_MAX"  # changed every minute, between two values that fly the same


def open_files(pid: int) -> int:
    try:
        return len(os.listdir(f"/proc/{pid}/fd"))
    except OSError:
        return -1


def threads(pid: int) -> int:
    try:
        return len(os.listdir(f"/proc/{pid}/task"))
    except OSError:
        return -1


def set_parameter(conn, value: float, timeout_s: float = 2.0) -> bool:
    """PARAM_SET as a ground tool sends it; True when the vehicle echoes the value.
    First the telemetry of the minute since the last one is read: a tool that never reads
    has a full socket buffer, and the kernel drops the echo (3 of 30 were lost so)."""
    while conn.recv_match(blocking=False) is not None:
        pass
    conn.mav.param_set_send(1, 1, PARAM, value, mavlink.MAV_PARAM_TYPE_REAL32)
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        msg = conn.recv_match(type="PARAM_VALUE", blocking=True, timeout=0.2)
        if msg is not None and msg.param_id == PARAM.decode() and abs(msg.param_value
                                                                       - value) < 1e-6:
            return True
    return False


def rss_mib(pid: int) -> float:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    return float("nan")


class MinuteTiming:
    """Jitter, compute and misses of the timing records received this minute, and the
    periods without a step: the records' times since the previous step, summed in whole
    periods, less the steps (a deadline miss, or a step held in a simulator stall: when a
    stall of the machine holds the simulator too, the autopilot counts the second, not the
    first). Summed, a late step and the early one after it cancel."""

    def __init__(self, period_s: float) -> None:
        self.period_s = period_s
        self.lock = threading.Lock()
        self.misses_seen = 0
        self.records = 0
        self.run_jitter = Histogram()  # the whole run's, for its p99 beside the minutes'
        self._fresh()

    def _fresh(self) -> None:
        self.jitter, self.compute = Histogram(), Histogram()
        self.misses_at_start = self.misses_seen
        self.stepped_s, self.stepped = 0.0, 0

    def on_sample(self, sample) -> None:
        timing_key = vehicle_key(1, AUTOPILOT, "timing")
        for key, payload, _ in unbatched(str(sample.key_expr), sample.payload.to_bytes(), None):
            if key != timing_key:
                continue
            r = TIMING.decode(payload)
            with self.lock:
                self.records += 1
                self.misses_seen = int(r["deadline_misses"])
                self.compute.add(float(r["compute_s"]))
                if r["period_s"] == r["period_s"]:  # NaN after a restart of the loop
                    self.jitter.add(abs(float(r["period_s"]) - self.period_s))
                    self.run_jitter.add(abs(float(r["period_s"]) - self.period_s))
                    self.stepped_s += float(r["period_s"])
                    self.stepped += 1

    def take(self) -> dict:
        with self.lock:
            j, c = self.jitter, self.compute
            out = {"steps": c.n, "misses": self.misses_seen - self.misses_at_start,
                   "periods_without_step": round(self.stepped_s / self.period_s)
                   - self.stepped,
                   "jitter_p50_ms": j.percentile(50) * 1e3,
                   "jitter_p99_ms": j.percentile(99) * 1e3, "jitter_max_ms": j.max_s * 1e3,
                   "compute_p99_ms": c.percentile(99) * 1e3}
            self._fresh()
        return out


class MinuteReference:
    """The reference sleeper's wake-ups this minute (from its reader thread), by when they
    are read; those due before ``restart`` (read late: cyclictest's backlog) are left
    out."""

    def __init__(self, period_s: float) -> None:
        self.period_s = period_s
        self.lock = threading.Lock()
        self.minute = ReferenceTally(period_s)
        self.total = ReferenceTally(period_s)
        self.total_summary = self.total.summary()
        self.since_s = -float("inf")

    def on_sample(self, t_s: float, latency_s: float) -> None:
        if t_s < self.since_s:
            return
        with self.lock:
            self.minute.add(latency_s)
            self.total.add(latency_s)

    def take(self) -> dict:
        """This minute's figures; the total so far is kept as of now (``total_summary``),
        so that it covers the same minutes as the rows."""
        with self.lock:
            got, self.minute = self.minute.summary(), ReferenceTally(self.period_s)
            self.total_summary = self.total.summary()
        return {"ref_wakeups": got["wakeups"], "ref_lost_periods": got["lost_periods"],
                "ref_worst_ms": got["worst_ms"], "ref_p99_ms": got["p99_ms"]}

    def restart(self) -> None:
        with self.lock:
            self.since_s = time.monotonic()
            self.minute, self.total = ReferenceTally(self.period_s), ReferenceTally(self.period_s)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--minutes", type=float, default=60.0)
    parser.add_argument("--rate-hz", type=float, default=250.0)
    parser.add_argument("--json", type=Path, help="also write the per-minute rows here")
    parser.add_argument("--keep", type=Path, help="run folder to keep (default: temporary)")
    parser.add_argument("--neighbours", type=int, default=0,
                        help="CPU-bound neighbours beside the vehicle")
    parser.add_argument("--nice", type=int, default=0, help="the neighbours' niceness")
    parser.add_argument("--rt-cpus", type=cpu_list, help="the vehicle processes' CPUs")
    parser.add_argument("--shield", action="store_true",
                        help="keep --rt-cpus for the vehicle processes (ivfm shield)")
    parser.add_argument("--reference", choices=(*CHOICES, "none"), default="auto",
                        help="the reference sleeper beside the soak (auto: cyclictest when "
                             "installed, else the built-in one)")
    args = parser.parse_args()
    # Stopped by a signal (a background job ignores SIGINT): clean up as after the last
    # minute, so that the neighbours end and the shield is lifted.
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(130))
    if args.shield:
        if args.rt_cpus is None:
            parser.error("--shield needs --rt-cpus")
        moved, refused = shield_cpus(args.rt_cpus)
        print(f"shield: {moved} threads moved off CPU {sorted(args.rt_cpus)}, "
              f"{refused} refused", flush=True)
    try:
        soak(args)
    finally:
        if args.shield:
            shield_cpus(None)


def soak(args: argparse.Namespace) -> None:
    duration_s = args.minutes * 60.0
    with tempfile.TemporaryDirectory() as tmp:
        out = args.keep or Path(tmp)
        out.mkdir(parents=True, exist_ok=True)
        endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
        sim_port, gcs_port = free_tcp_port(), free_udp_port()
        logger = LoggerProcess(out, endpoint, out / "logger.txt")
        zenoh_args = ["--zenoh-connect", endpoint, "--perturbations"]
        if args.rt_cpus is not None:
            zenoh_args += ["--rt-cpus", ",".join(map(str, sorted(args.rt_cpus)))]
        logs = {name: open(out / f"{name}.txt", "w") for name in ("sitl", "autopilot")}  # noqa: SIM115
        procs = {"logger": logger.proc}
        procs["sitl"] = subprocess.Popen(
            [sys.executable, "-m", "sitl", "--port", str(sim_port), "--realtime",
             "--rate-hz", str(args.rate_hz), "--start-altitude", "1.0",
             "--exit-on-disconnect", *zenoh_args], stdout=logs["sitl"], stderr=subprocess.STDOUT)
        procs["autopilot"] = subprocess.Popen(
            [sys.executable, "-m", "autopilot", "--sim", f"127.0.0.1:{sim_port}", "--realtime",
             "--rate-hz", str(args.rate_hz), "--reference", "attitude-sine",
             "--arm-in-reference", "--duration", str(duration_s + 5.0),
             "--gcs-bind", str(gcs_port),
             "--api", "none", "--api-bind", "0", *zenoh_args],
            stdout=logs["autopilot"], stderr=subprocess.STDOUT)
        nice = f"nice -n {args.nice} " if args.nice else ""
        neighbours = [subprocess.Popen(
            ["bash", "-c", NEIGHBOUR.format(nice=nice, out=out / f"neighbour-{i}")],
            start_new_session=True) for i in range(args.neighbours)]
        timing = MinuteTiming(1.0 / args.rate_hz)
        reference = MinuteReference(1.0 / args.rate_hz)
        sleeper = None
        if args.reference != "none":
            sleeper = ReferenceSleeper(1.0 / args.rate_hz, reference.on_sample,
                                       AUTOPILOT_RT_PRIORITY, args.rt_cpus, args.reference)
        session = open_session(ZenohOptions(mode="peer", connect=[endpoint], listen=[]))
        sub = session.declare_subscriber(vehicle_key(1, AUTOPILOT, BATCH_TOPIC),
                                         timing.on_sample)
        station = GroundStation(GroundStationPlan(heartbeat_hz=1.0, offboard_at_s=5.0,
                                                  setpoint_hz=20.0),
                                gcs_port, 1, (0.0, 0.0, -1.0), 0.0)
        from pymavlink import mavutil

        tool = mavutil.mavlink_connection(f"udpout:127.0.0.1:{gcs_port}", source_system=254)
        perturb = PerturbationClient(session=session, timeout_s=5.0)
        rows = []
        try:
            start = time.monotonic()
            while timing.records == 0 and time.monotonic() - start < 120.0:
                time.sleep(0.1)  # the loop is running
            if sleeper is not None:
                sleeper.start()
                print(f"reference: {sleeper.describe()}", flush=True)
            station.start()
            start = time.monotonic()
            timing.take()
            reference.restart()
            minute = 0
            while minute < args.minutes and procs["autopilot"].poll() is None:
                time.sleep(max(0.0, start + 60.0 * minute + 20.0 - time.monotonic()))
                tool.mav.heartbeat_send(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID,
                                        0, 0, 0)
                param_ok = set_parameter(tool, 12.0 if minute % 2 else 11.0)
                try:
                    wind = perturb.perturb(1, "wind", duration_s=10.0, ned_mps=[1.0, 0.5, 0.0])
                    wind_ok = bool(wind.get("ok"))
                except RuntimeError:
                    wind_ok = False
                time.sleep(max(0.0, start + 60.0 * (minute + 1) - time.monotonic()))
                minute += 1
                row = {"minute": minute, **timing.take(), **reference.take(),
                       "param_acked": param_ok,
                       "wind_acked": wind_ok,
                       **{f"rss_{n}_mib": round(rss_mib(p.pid), 1) for n, p in procs.items()},
                       **{f"fds_{n}": open_files(p.pid) for n, p in procs.items()},
                       **{f"threads_{n}": threads(p.pid) for n, p in procs.items()}}
                rows.append(row)
                ref = (f"reference lost {row['ref_lost_periods']:3d} worst "
                       f"{row['ref_worst_ms']:6.2f} ms  " if sleeper is not None else "")
                print(f"min {minute:3d}  steps {row['steps']:6d}  misses {row['misses']:3d}  "
                      f"without a step {row['periods_without_step']:3d}  " + ref +
                      f"jitter p50/p99/max {row['jitter_p50_ms']:.3f}/{row['jitter_p99_ms']:.3f}/"
                      f"{row['jitter_max_ms']:.3f} ms  compute p99 {row['compute_p99_ms']:.3f} ms"
                      f"  RSS MiB " + " ".join(f"{n} {row[f'rss_{n}_mib']:.1f}" for n in procs)
                      + "  fds/threads " + " ".join(f"{row[f'fds_{n}']}/{row[f'threads_{n}']}"
                                                   for n in procs)
                      + f"  param {'ok' if param_ok else 'NOT acked'}"
                      f"  wind {'ok' if wind_ok else 'NOT acked'}", flush=True)
        except SystemExit:  # SIGTERM: the summary of the minutes so far, then out
            print(f"stopped by a signal after {len(rows)} minutes", flush=True)
        finally:
            if sleeper is not None:
                sleeper.stop()
            station.stop()
            tool.close()
            for neighbour in neighbours:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(neighbour.pid, signal.SIGKILL)
                neighbour.wait()
            for name in ("autopilot", "sitl"):
                if procs[name].poll() is None:
                    procs[name].terminate()
                    procs[name].wait(timeout=30.0)
                logs[name].close()
            try:
                final = logger.wait_until(session, [vehicle_key(1, p, "status")
                                                    for p in (SITL, AUTOPILOT)],
                                          final=True, timeout_s=30.0)
                accounting = telemetry_accounting(final)
            except RuntimeError as exc:
                accounting = {"error": str(exc)}
            sub.undeclare()
            session.close()
            logger.stop()
        if "error" in accounting:
            print(f"published vs logged: {accounting['error']}")
        else:
            print(f"published {sum(accounting['published'].values())} records, logged "
                  f"{sum(accounting['logged'].values())}, lost {accounting['lost'] or 0}")
        if rows:
            first = rows[0]
            print("RSS change from the first minute to the last: " + ", ".join(
                f"{n} {100 * (rows[-1][f'rss_{n}_mib'] / first[f'rss_{n}_mib'] - 1):+.1f} % "
                f"(max {100 * (max(r[f'rss_{n}_mib'] for r in rows) / first[f'rss_{n}_mib'] - 1):+.1f} %)"  # noqa: E501
                for n in procs))
            print(f"total misses {sum(r['misses'] for r in rows)}, periods without a step "
                  f"{sum(r['periods_without_step'] for r in rows)}, jitter p99 "
                  f"{timing.run_jitter.percentile(99) * 1e3:.3f} ms over the run (worst "
                  f"minute {max(r['jitter_p99_ms'] for r in rows):.3f} ms, "
                  f"{sum(r['jitter_p99_ms'] > 0.2 for r in rows)} minutes over 0.2 ms)")
        totals = None
        if sleeper is not None:
            totals = {**summary(sleeper, reference.total), **reference.total_summary}
            print(f"reference ({sleeper.describe()}): {totals['lost_periods']} periods lost "
                  f"in {totals['late_wakeups']} late wake-ups of {totals['wakeups']}, worst "
                  f"{totals['worst_ms']:.2f} ms, p99 {totals['p99_ms']:.3f} ms")
        if args.json:
            args.json.write_text(json.dumps({
                "minutes": rows, "total_misses": sum(r["misses"] for r in rows),
                "total_periods_without_step": sum(r["periods_without_step"] for r in rows),
                "jitter_p99_ms": timing.run_jitter.percentile(99) * 1e3,
                "reference": totals}, indent=1))


if __name__ == "__main__":
    main()
