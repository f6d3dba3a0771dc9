"""Ground-link flood benchmark: does traffic on the GCS / API ports cost the control loop
a deadline?

Runs logger + simulator + autopilot in real time (attitude-sine reference, armed from the
first sample), with a pymavlink "tool" on its own port that, once a second, sends a
HEARTBEAT, a PARAM_REQUEST_READ and a COMMAND_LONG and times the answers. In each
flooded row a generator process sends datagrams from loopback to the autopilot's GCS
(and API) port for ``--flood-s`` seconds, started once the tool has been answered; the
run lasts ``--flood-s`` + 2 s of control. Prints a table: deadline misses, jitter
p50/p99/max, datagrams the vehicle read / the kernel dropped, and the tool's worst
answer times.

    python tests/benchmarks/bench_flood.py                  # 250 Hz, the full table
    python tests/benchmarks/bench_flood.py --rows calm,garbage-gcs --rate-hz 100

Loopback only, bounded in time (each row ends with its run); asserts nothing.
"""

from __future__ import annotations

import argparse
import json
import os
import random
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from contracts.mavlink import mavlink, new_mavlink  # noqa: E402
from ground.run.children import LoggerProcess, free_tcp_port  # noqa: E402

# name -> (kind, rate per second, ports flooded, source ports)
ROWS = {
    "calm": (None, 0, (), 0),
    "garbage-gcs": ("garbage", 100_000, ("gcs",), 1),
    "garbage-both": ("garbage", 100_000, ("gcs", "api"), 1),
    "valid20k-gcs": ("heartbeat", 20_000, ("gcs",), 200),
    "valid-gcs": ("heartbeat", 100_000, ("gcs",), 200),
    "valid-both": ("heartbeat", 100_000, ("gcs", "api"), 400),
}


def free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


# -- the flood generator (a child process: it needs a core of its own) --------------------
def generate(kind: str, rate: float, ports: list[int], sources: int, duration_s: float,
             seed: int = 1) -> None:
    rng = random.Random(seed)
    socks = []
    for _ in range(max(1, sources)):
        s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        s.bind(("127.0.0.1", 0))
        s.setblocking(False)
        socks.append(s)
    if kind == "garbage":
        frames = [rng.randbytes(rng.randint(1, 280)) for _ in range(4096)]
    else:  # valid MAVLink 2 HEARTBEATs, one system id per source port
        frames = [mavlink.MAVLink_heartbeat_message(
            mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3).pack(
            new_mavlink(1 + i % 250, 190)) for i in range(len(socks))]
    targets = [("127.0.0.1", p) for p in ports]
    sent = failed = 0
    start = time.perf_counter()
    end = start + duration_s
    i = 0
    while True:
        now = time.perf_counter()
        if now >= end:
            break
        due = int((now - start) * rate)
        while sent + failed < due:
            sock = socks[i % len(socks)]
            try:
                sock.sendto(frames[i % len(frames)], targets[i % len(targets)])
                sent += 1
            except OSError:
                failed += 1
            i += 1
        time.sleep(0.0005)
    print(json.dumps({"sent": sent, "failed": failed,
                      "rate_per_s": sent / (time.perf_counter() - start)}), flush=True)


# -- the tool --------------------------------------------------------------------------
class Tool:
    """A pymavlink client on its own port. Once a second it sends a HEARTBEAT, asks for a
    parameter and sends a command; it times PARAM_VALUE and COMMAND_ACK (a request not
    answered within a second counts as unanswered, and is asked again) and the longest
    gap between the vehicle's HEARTBEATs."""

    ANSWERS = ("PARAM_VALUE", "COMMAND_ACK")

    def __init__(self, vehicle_port: int) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.setblocking(False)
        self.vehicle = ("127.0.0.1", vehicle_port)
        self.mav = new_mavlink(245, 190)
        self.reset(None)

    def reset(self, now: float | None) -> None:
        self.asked_s: dict[str, float] = {}
        self.worst_s = dict.fromkeys(self.ANSWERS, 0.0)
        self.answered = dict.fromkeys(self.ANSWERS, 0)
        self.unanswered = dict.fromkeys(self.ANSWERS, 0)
        self.last_heartbeat_s = now
        self.heartbeat_gap_s = 0.0

    def send(self, msg) -> None:
        self.sock.sendto(msg.pack(self.mav), self.vehicle)

    def ask(self, now: float) -> None:
        for kind, when in list(self.asked_s.items()):
            if now - when > 1.0:
                self.unanswered[kind] += 1
                del self.asked_s[kind]
        self.send(mavlink.MAVLink_heartbeat_message(
            mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3))
        self.send(mavlink.MAVLink_param_request_read_message(1, 1, b"MPC_XY_VEL_MAX", -1))
        self.send(mavlink.MAVLink_command_long_message(
            1, 1, mavlink.MAV_CMD_REQUEST_MESSAGE, 0,
            mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION, 0, 0, 0, 0, 0, 0))
        for kind in self.ANSWERS:
            self.asked_s.setdefault(kind, now)

    def read(self, now: float) -> bool:
        """Read what came; True if the vehicle's HEARTBEAT was among it."""
        heartbeat = False
        parser = new_mavlink(245, 190)
        while True:
            try:
                data = self.sock.recv(65535)
            except BlockingIOError:
                return heartbeat
            for msg in parser.parse_buffer(data) or []:
                kind = msg.get_type()
                if kind == "HEARTBEAT":
                    heartbeat = True
                    if self.last_heartbeat_s is not None:
                        self.heartbeat_gap_s = max(self.heartbeat_gap_s,
                                                   now - self.last_heartbeat_s)
                    self.last_heartbeat_s = now
                elif kind in self.asked_s:
                    self.worst_s[kind] = max(self.worst_s[kind], now - self.asked_s.pop(kind))
                    self.answered[kind] += 1

    def summary(self, now: float) -> dict:
        gap = max(self.heartbeat_gap_s, now - (self.last_heartbeat_s or now))
        return {"heartbeat_gap_max_s": round(gap, 3),
                **{f"{k.lower()}_worst_s": round(v, 3) for k, v in self.worst_s.items()},
                "answered": self.answered, "unanswered": self.unanswered}


def run_row(name: str, rate_hz: float, flood_s: float, folder: Path) -> dict:
    kind, rate, flooded, sources = ROWS[name]
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    sim_port, gcs_port, api_port = free_tcp_port(), free_udp_port(), free_udp_port()
    out = folder / name
    out.mkdir(parents=True, exist_ok=True)
    logger = LoggerProcess(out, endpoint, out / "logger.txt")
    zenoh_args = ["--zenoh-connect", endpoint]
    sim_log, ap_log = open(out / "sitl.txt", "w"), open(out / "autopilot.txt", "w")  # noqa: SIM115
    sim = subprocess.Popen(
        [sys.executable, "-m", "sitl", "--port", str(sim_port), "--realtime", "--rate-hz",
         str(rate_hz), "--start-altitude", "1.0", "--exit-on-disconnect", *zenoh_args],
        stdout=sim_log, stderr=subprocess.STDOUT)
    autopilot = subprocess.Popen(
        [sys.executable, "-m", "autopilot", "--sim", f"127.0.0.1:{sim_port}", "--realtime",
         "--rate-hz", str(rate_hz), "--reference", "attitude-sine", "--arm-in-reference",
         "--duration", str(flood_s + 2.0), "--gcs-bind", str(gcs_port), "--gcs", "none",
         "--api-bind", str(api_port), "--api", "none", *zenoh_args],
        stdout=ap_log, stderr=subprocess.STDOUT)
    tool = Tool(gcs_port)
    tool_summary: dict = {}
    flood = None
    next_ask = 0.0
    connected = False
    try:
        deadline = time.monotonic() + 120.0
        while autopilot.poll() is None and time.monotonic() < deadline:
            now = time.monotonic()
            if tool.read(now) and not connected:
                connected = True
                tool.reset(now)  # count from the flood on
                if kind is not None:
                    ports = [gcs_port if p == "gcs" else api_port for p in flooded]
                    flood = subprocess.Popen(
                        [sys.executable, __file__, "--generate", kind, str(rate),
                         ",".join(map(str, ports)), str(sources), str(flood_s)],
                        stdout=subprocess.PIPE, text=True)
            if now >= next_ask:
                tool.ask(now)
                next_ask = now + 1.0
            if flood is not None and flood.poll() is not None and not tool_summary:
                tool_summary = tool.summary(now)  # the flood is over
            time.sleep(0.01)
        tool_summary = tool_summary or tool.summary(time.monotonic())
        autopilot.wait(timeout=30.0)
        sim.wait(timeout=30.0)
    finally:
        for proc in (autopilot, sim):
            if proc.poll() is None:
                proc.kill()
        logger.stop()
        sim_log.close()
        ap_log.close()
    flood_stats = json.loads(flood.communicate(timeout=60.0)[0]) if flood else {}
    timing, links = {}, {}
    for line in (out / "autopilot.txt").read_text().splitlines():
        if line.startswith("autopilot: timing "):
            timing = json.loads(line.removeprefix("autopilot: timing "))
        if line.startswith("autopilot: ground links "):
            links = json.loads(line.removeprefix("autopilot: ground links "))
    return {"row": name, "timing": timing, "flood": flood_stats, "links": links,
            "tool": tool_summary}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--rows", default=",".join(ROWS),
                        help=f"comma-separated, of: {', '.join(ROWS)}")
    parser.add_argument("--rate-hz", type=float, default=250.0)
    parser.add_argument("--flood-s", type=float, default=10.0)
    parser.add_argument("--json", type=Path, help="also write the results here")
    parser.add_argument("--keep", type=Path, help="keep the processes' logs in this folder")
    parser.add_argument("--generate", nargs=5, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.generate:
        kind, rate, ports, sources, duration = args.generate
        os.nice(5)  # the generator stands for another machine: it must not outrank us
        generate(kind, float(rate), [int(p) for p in ports.split(",")], int(sources),
                 float(duration))
        return
    results = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = args.keep or tmp
        for name in args.rows.split(","):
            if name not in ROWS:
                parser.error(f"unknown row {name!r}")
            r = run_row(name, args.rate_hz, args.flood_s, Path(tmp))
            results.append(r)
            t = r["timing"]
            print(f"{name:14s} steps {t.get('steps', 0):6d}  misses {t.get('deadline_misses')!s:>5}"
                  f"  jitter p50/p99/max {t.get('jitter_p50_ms', float('nan')):.3f}/"
                  f"{t.get('jitter_p99_ms', float('nan')):.3f}/"
                  f"{t.get('jitter_max_ms', float('nan')):.3f} ms"
                  f"  compute p99 {t.get('compute_p99_ms', float('nan')):.3f} ms"
                  f"  flood {r['flood'].get('rate_per_s', 0):8.0f}/s"
                  , flush=True)
            print(f"{'':14s} tool {json.dumps(r['tool'])}", flush=True)
            if r["links"]:
                print(f"{'':14s} links {json.dumps(r['links'])}", flush=True)
    if args.json:
        args.json.write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
