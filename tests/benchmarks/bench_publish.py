"""What publishing telemetry adds to a control step (the issue's aim: under 20 us).

    python tests/benchmarks/bench_publish.py

Runs the autopilot's real control step (``Autopilot._control``: requests, sample, the IVFC
law, then the control record, the timing record and the MAVLink mirror) on a hovering
measurement, once with Zenoh off and once with a real session whose records a logger
process on loopback receives. Prints per-step times; asserts nothing.
"""

from __future__ import annotations

import socket
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

import numpy as np  # noqa: E402

from autopilot.commander.commander import Commander  # noqa: E402
from autopilot.control.factory import load_models, make_controller  # noqa: E402
from autopilot.mavlink.link import open_link  # noqa: E402
from autopilot.mavlink.server import MavlinkServer  # noqa: E402
from autopilot.process.loop import Autopilot, AutopilotConfig  # noqa: E402
from autopilot.trajectories import Reference  # noqa: E402
from contracts.airframe import PAPER  # noqa: E402
from contracts.zenoh_link import ZenohOptions  # noqa: E402
from ground.run.children import LoggerProcess  # noqa: E402

STEPS = 20000


def autopilot(zenoh: ZenohOptions) -> Autopilot:
    models = load_models(None)
    vehicle = Commander(lambda p: make_controller("ivfc", PAPER, 0.01, models, p), 0.01, {},
                      Reference("attitude-sine"))
    ground = MavlinkServer(vehicle, [open_link("gcs", ("127.0.0.1", 0), None, None, 0)])
    ap = Autopilot(AutopilotConfig(zenoh=zenoh), vehicle, ground, arm_in_reference=True,
                   log=lambda _t: None)
    ap._warm_up()
    return ap


def step_times(ap: Autopilot, publish_only: bool = False) -> np.ndarray:
    hover = np.zeros(12)
    hover[2] = -1.0
    times = np.zeros(STEPS)
    for k in range(STEPS):
        t_us = k * 10_000
        start = time.perf_counter()
        if publish_only:
            ap.telemetry.publish_step(t_us, 1e-5, start)
        else:
            ap._control(t_us, hover)
        times[k] = time.perf_counter() - start
    return times[1000:] * 1e6


def show(label: str, us: np.ndarray) -> None:
    print(f"{label:<44} mean {us.mean():6.1f} us  p50 {np.percentile(us, 50):6.1f}  "
          f"p99 {np.percentile(us, 99):6.1f}  max {us.max():7.1f}")


def main() -> None:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        endpoint = f"tcp/127.0.0.1:{s.getsockname()[1]}"
    with tempfile.TemporaryDirectory() as tmp:
        logger = LoggerProcess(Path(tmp), endpoint, Path(tmp) / "logger.log")
        try:
            off = autopilot(ZenohOptions(enabled=False))
            on = autopilot(ZenohOptions(listen=["tcp/127.0.0.1:0"], connect=[endpoint]))
            deadline = time.monotonic() + 20
            while not on.telemetry.control_pub.matched and time.monotonic() < deadline:
                time.sleep(0.05)
            print(f"logger subscribed: {on.telemetry.control_pub.matched}")
            rounds = {"off": [], "on": [], "publish": []}
            for _ in range(3):  # interleaved, so machine noise hits both alike
                rounds["off"].append(step_times(off))
                rounds["on"].append(step_times(on))
                rounds["publish"].append(step_times(on, publish_only=True))
            off_us, on_us = np.concatenate(rounds["off"]), np.concatenate(rounds["on"])
            show("control step, Zenoh off", off_us)
            show("control step, Zenoh on (logger receiving)", on_us)
            show("the publishing alone (publish_step)", np.concatenate(rounds["publish"]))
            added = [statistics.mean(b) - statistics.mean(a)
                     for a, b in zip(rounds["off"], rounds["on"], strict=True)]
            print(f"publishing adds {statistics.mean(added):.1f} us per control step "
                  f"(rounds: {', '.join(f'{a:.1f}' for a in added)}); aim < 20 us")
            on.node.close()
        finally:
            logger.stop()


if __name__ == "__main__":
    main()
