"""MAVSDK-Python's own examples, unchanged (tests/groundtools/mavsdk_examples/), against
the real processes, as a new PX4 user runs them: each runs to its end, and a pymavlink
ground station on the GCS link watches what the vehicle did.

The examples connect ``udpin://0.0.0.0:14540`` (the autopilot's API link sends there):
one at a time on this machine (the api_port_14540 fixture's lock)."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from pymavlink import mavutil

from contracts.mavlink import API_UDP_PORT
from tests.harness import GroundTool, start_processes

pytestmark = [pytest.mark.process, pytest.mark.groundtool,
              pytest.mark.usefixtures("api_port_14540")]

EXAMPLES = Path(__file__).parent / "mavsdk_examples"
M = mavutil.mavlink
INT32 = M.MAV_PARAM_TYPE_INT32
API = ["--api", f"127.0.0.1:{API_UDP_PORT}", "--api-bind", "0"]


def _value(msg) -> float:
    """A PARAM_VALUE's value, byte-wise decoded for INT32 (PX4's encoding)."""
    from autopilot.mavlink.params import float_as_int32

    return float(float_as_int32(msg.param_value)) if msg.param_type == INT32 \
        else msg.param_value


def run_example(name: str, gcs: GroundTool, timeout_s: float, log: Path) -> dict:
    """Run one example to its end while ``gcs`` records what the vehicle says and does."""
    seen: dict = {"params": [], "modes": [], "armed": [], "rel_alt_m": [], "ned": []}
    with open(log, "w") as out:
        # Its own session: the example and the mavsdk_server it starts are stopped together,
        # so no server outlives it on udpin 14540 to take the next example's replies.
        example = subprocess.Popen(
            [sys.executable, str(EXAMPLES / "run_grpc_example.py"), str(EXAMPLES / name)],
            stdout=out, stderr=subprocess.STDOUT, start_new_session=True)
        start = time.monotonic()
        try:
            while example.poll() is None and time.monotonic() - start < timeout_s:
                msg = gcs.pump()
                if msg is None:
                    continue
                t = time.monotonic() - start
                kind = msg.get_type()
                if kind == "PARAM_VALUE":
                    seen["params"].append((t, msg.param_id, _value(msg)))
                elif kind == "HEARTBEAT" and msg.get_srcComponent() == 1:
                    seen["modes"].append((t, (msg.custom_mode >> 16) & 0xFF,
                                          (msg.custom_mode >> 24) & 0xFF))
                    seen["armed"].append((t, bool(msg.base_mode & 128)))
                elif kind == "GLOBAL_POSITION_INT":
                    seen["rel_alt_m"].append((t, msg.relative_alt / 1000.0))
                elif kind == "LOCAL_POSITION_NED":
                    seen["ned"].append((t, msg.x, msg.y, msg.z))
        finally:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(example.pid, signal.SIGKILL)  # the example, if it still runs,
            example.wait(10)  # and whatever it started
    seen["returncode"] = example.returncode
    seen["output"] = log.read_text()
    seen["texts"] = list(gcs.texts)
    seen["seconds"] = time.monotonic() - start
    return seen


def _fly(tmp_path: Path, example: str, timeout_s: float, sim_args=(), autopilot_args=()):
    procs = start_processes(tmp_path, sim_args=list(sim_args),
                            autopilot_args=[*API, *autopilot_args])
    gcs = GroundTool(procs.gcs_port)
    try:
        gcs.connect(60)
        # Started once the vehicle is ready to arm, as a user starts it when the vehicle
        # says so: the example's own wait (global position and home ok) can pass while
        # the estimator is still converging, and arming is denied until it has.
        gcs.wait_type("SYS_STATUS", 90,
                      lambda m: m.onboard_control_sensors_health & M.MAV_SYS_STATUS_PREARM_CHECK)
        seen = run_example(example, gcs, timeout_s, tmp_path / "example.log")
        after = time.monotonic() + 3.0  # what the vehicle does after the example's end
        while time.monotonic() < after:
            if (msg := gcs.pump(0.05)) is not None and msg.get_type() == "HEARTBEAT" \
                    and msg.get_srcComponent() == 1:
                seen["modes"].append((seen["seconds"], (msg.custom_mode >> 16) & 0xFF,
                                      (msg.custom_mode >> 24) & 0xFF))
                seen["armed"].append((seen["seconds"], bool(msg.base_mode & 128)))
        seen["texts"] = list(gcs.texts)
    finally:
        gcs.close()
        procs.stop()
    assert seen["returncode"] == 0, seen["output"][-3000:]
    return seen


def _first(seen: dict, fragment: str) -> str:
    found = [t for t in seen["texts"] if fragment in t]
    assert found, (fragment, seen["texts"])
    return found[0]


def test_failure_injection_example_runs_to_its_end_and_the_gps_loss_lands_the_vehicle(
        tmp_path):
    seen = _fly(tmp_path, "failure_injection.py", 120,
                sim_args=["--sensors", "typical"],
                autopilot_args=["--state-source", "estimator"])
    out = seen["output"]
    assert out.rstrip().endswith("-- Disabling failure injection"), out[-2000:]
    # set_param_int: SYS_FAILURE_EN went to 1 and back to 0 (echoed on the GCS link too)
    assert [v for _, n, v in seen["params"] if n == "SYS_FAILURE_EN"] == [1.0, 0.0]
    assert any(armed for _, armed in seen["armed"])
    top = max(alt for _, alt in seen["rel_alt_m"])
    assert 20.0 < top < 24.0, top  # the goto 20 m above where the take-off left it
    _first(seen, "failure injected: GPS off")
    _first(seen, "GPS lost: dead reckoning")
    _first(seen, "position lost: no GPS fix for 5 s")
    assert seen["modes"][-1][1:] == (4, 6)  # AUTO.LAND when the example ends
    print(f"example ran {seen['seconds']:.1f} s; highest {top:.2f} m")


def test_follow_me_example_runs_to_its_end_following_then_landing(tmp_path):
    seen = _fly(tmp_path, "follow_me_example.py", 120)
    out = seen["output"]
    assert out.rstrip().endswith("-- Landing"), out[-2000:]
    params = {n: v for _, n, v in seen["params"]}
    # Config(8 m height, 2 m distance, responsiveness 0.02, TARGET_GPS, 10 m/s, 0 deg):
    # MAVSDK reads the values first and sets only those that differ (FLW_TGT_HT is 8)
    assert "FLW_TGT_HT" not in params
    assert params["FLW_TGT_DST"] == pytest.approx(2.0)
    assert params["FLW_TGT_RS"] == pytest.approx(0.02)
    assert params["FLW_TGT_ALT_M"] == 2.0  # TARGET_GPS, an INT32 set with set_param_int
    assert params["FLW_TGT_MAX_VEL"] == pytest.approx(10.0)
    assert params["FLW_TGT_FA"] == pytest.approx(0.0)
    assert any(armed for _, armed in seen["armed"])
    followed = [t for t, main, sub in seen["modes"] if (main, sub) == (4, 8)]
    assert followed, seen["modes"]  # AUTO.FOLLOW_TARGET
    # towards the first fake target, 33 m north of home: the vehicle went north
    north = max(x for t, x, _, _ in seen["ned"] if followed[0] <= t)
    assert north > 5.0, north
    # The fake target is at 480 m AMSL; tracking its altitude 8 m above it is 488 m,
    # home's ground: the vehicle follows it down to the ground (as PX4 SITL at its
    # 488 m Zurich home would).
    texts = seen["texts"]
    assert texts.index("mode follow_target") < texts.index("landed")
    # stop: HOLD; land: LAND, on the ground already, so disarmed at once
    assert texts.index("landed") < texts.index("mode hold", texts.index("landed")) \
        < texts.index("mode land") < texts.index("landed: disarmed")
    assert not seen["armed"][-1][1]
    print(f"example ran {seen['seconds']:.1f} s; north {north:.1f} m; "
          f"{len(followed)} heartbeats in FOLLOW_TARGET")
