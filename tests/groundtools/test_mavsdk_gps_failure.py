"""MAVSDK's failure plugin switches the GPS off on a vehicle flying on its estimator, as a
PX4 user rehearses a GPS loss: the vehicle dead-reckons, then past EKF2_NOAID_TOUT calls
its position lost and lands, as PX4 does; the MCAP log of the ground station's logger
records the injection and what followed."""

from __future__ import annotations

import asyncio
import contextlib
import subprocess
import sys
import time

import pytest
from mavsdk.asyncio.plugins.action import ActionAsync
from mavsdk.asyncio.plugins.failure import FailureType, FailureUnit
from mavsdk.asyncio.plugins.param import ParamAsync
from mavsdk.asyncio.plugins.telemetry import TelemetryAsync

from tests.ground.test_ground_station import free_tcp_port
from tests.groundtools.test_mavsdk import _near, _until
from tests.harness import start_processes
from tests.mavsdk_helpers import autopilot_on, inject_enabled

pytestmark = [pytest.mark.process, pytest.mark.groundtool]


async def _fly(port: int) -> dict:
    seen: dict = {"texts": []}
    async with autopilot_on(port) as system:
        action, telem = ActionAsync(system), TelemetryAsync(system)
        param = ParamAsync(system)

        async def collect():
            async for status in telem.subscribe_status_text():
                seen["texts"].append((time.monotonic(), status.text))
        texts = asyncio.ensure_future(collect())

        async def healthy():  # the estimator has converged: arming is allowed
            h = await telem.health()
            return h.is_local_position_ok and h.is_armable
        await _until(healthy, 30, "health")

        async def down_m():
            return (await telem.position_velocity_ned()).position.down_m

        await action.set_takeoff_altitude(2.0)
        await action.arm()
        await action.takeoff()
        await _until(lambda: _near(down_m, -2.0, 0.2), 20, "take-off altitude")
        await asyncio.sleep(2.0)  # the take-off settles into the hold
        seen["injected_s"] = time.monotonic()
        await inject_enabled(system, param, FailureUnit.SENSOR_GPS, FailureType.OFF, 0)

        async def disarmed():
            return not await telem.armed()
        await _until(disarmed, 30, "landed and disarmed")
        seen["disarmed_s"] = time.monotonic()
        await asyncio.sleep(0.5)
        texts.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await texts
    return seen


def _first(seen: dict, fragment: str) -> float:
    """Seconds after the injection when a text holding ``fragment`` arrived."""
    for t, text in seen["texts"]:
        if fragment in text:
            return t - seen["injected_s"]
    raise AssertionError(f"no text with {fragment!r}: {[t for _, t in seen['texts']]}")


def test_mavsdk_gps_off_dead_reckons_then_lands_and_the_log_has_it(tmp_path):
    from ground.record.events import statustext_events

    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    logger = subprocess.Popen(
        [sys.executable, "-m", "ground.cli", "ground", "log", "--out", str(tmp_path / "log"),
         "--zenoh-listen", endpoint], stdout=subprocess.DEVNULL, stderr=subprocess.STDOUT)
    procs = start_processes(tmp_path, sim_args=["--sensors", "typical", "--zenoh-connect",
                                                endpoint],
                            # Failure injection on from the start, as on a PX4 vehicle
                            # configured for it: MAVSDK's plugin reads 1 when it starts.
                            # (Set by set_param_int mid-flight, the plugin's own copy
                            # once stayed 0 for over 5 s beside a CPU-bound neighbour:
                            # not traced; test_mavsdk_failure.py flies that path.)
                            autopilot_args=["--state-source", "estimator", "--zenoh-connect",
                                            endpoint, "--param", "SYS_FAILURE_EN=1"])
    try:
        seen = asyncio.run(_fly(procs.gcs_port))
    finally:
        procs.stop()
        logger.terminate()
        logger.wait(10)
    assert _first(seen, "failure injected: GPS off") < 1.0
    lost = _first(seen, "GPS lost: dead reckoning")
    assert 0.8 < lost < 2.0  # no fix fused for 1 s
    position_lost = _first(seen, "position lost: no GPS fix for 5 s: land")
    assert 4.5 < position_lost < 6.5  # EKF2_NOAID_TOUT, 5 s after the last fix fused
    assert seen["disarmed_s"] - seen["injected_s"] > position_lost
    print(f"after GPS OFF: dead reckoning at {lost:.2f} s, position lost at "
          f"{position_lost:.2f} s, disarmed at {seen['disarmed_s'] - seen['injected_s']:.2f} s")
    logged = [e.text for e in statustext_events(tmp_path / "log", 1)]
    for text in ("failure injected: GPS off", "GPS lost: dead reckoning",
                 "position lost: no GPS fix for 5 s: land", "landed"):
        assert any(text in t for t in logged), (text, logged)
