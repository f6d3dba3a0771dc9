"""MAVSDK (PyPI ``mavsdk`` 4.x, the native binding) flies the real processes.

Connect, health (home and position ok), arm, take off, hold, offboard to a position
and back, land, disarm: the flow of MAVSDK's own examples, against our autopilot.
"""

from __future__ import annotations

import asyncio
import time

import pytest
from mavsdk import log_subscribe
from mavsdk.asyncio.plugins.action import ActionAsync
from mavsdk.asyncio.plugins.offboard import OffboardAsync, PositionNedYaw
from mavsdk.asyncio.plugins.telemetry import FlightMode, LandedState, TelemetryAsync

from tests.harness import start_processes
from tests.mavsdk_helpers import autopilot_on

pytestmark = [pytest.mark.process, pytest.mark.groundtool]

log_subscribe(lambda level, text, file, line: level.value < 2)  # warnings and errors only


async def _until(check, timeout_s: float, what: str):
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        value = await check()
        if value:
            return value
        await asyncio.sleep(0.1)
    raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")


async def _fly(port: int) -> list[str]:
    steps = []
    async with autopilot_on(port) as system:
        action, telem, offboard = ActionAsync(system), TelemetryAsync(system), \
            OffboardAsync(system)

        async def healthy():
            h = await telem.health()
            return (h.is_global_position_ok and h.is_home_position_ok
                    and h.is_local_position_ok and h.is_armable)
        await _until(healthy, 20, "health")
        steps.append("healthy")

        await action.set_takeoff_altitude(2.0)
        assert await action.get_takeoff_altitude() == 2.0
        await action.arm()
        await _until(telem.armed, 5, "armed")
        steps.append("armed")

        async def down_m():
            return (await telem.position_velocity_ned()).position.down_m

        await action.takeoff()
        await _until(telem.in_air, 10, "in air")
        await _until(lambda: _near(down_m, -2.0, 0.15), 20, "take-off altitude")
        steps.append("took off")

        await action.hold()
        await _until(lambda: _mode_is(telem, FlightMode.HOLD), 5, "hold mode")
        steps.append("holding")

        async def north_east():
            p = (await telem.position_velocity_ned()).position
            return p.north_m, p.east_m

        await offboard.set_position_ned(PositionNedYaw(1.5, -1.0, -2.5, 0.0))
        await offboard.start()
        await _until(lambda: _mode_is(telem, FlightMode.OFFBOARD), 5, "offboard mode")
        await _until(lambda: _near_xy(north_east, 1.5, -1.0, 0.15), 25, "offboard setpoint")
        await offboard.set_position_ned(PositionNedYaw(0.0, 0.0, -2.0, 0.0))
        await _until(lambda: _near_xy(north_east, 0.0, 0.0, 0.15), 25, "back to origin")
        await offboard.stop()
        await _until(lambda: _mode_is(telem, FlightMode.HOLD), 5, "hold after offboard")
        steps.append("offboard there and back")

        await action.land()
        await _until(lambda: _landed(telem), 30, "on the ground")
        await action.disarm()
        await _until(lambda: _not(telem.armed), 10, "disarmed")
        steps.append("landed and disarmed")
    return steps


async def _near(read, target: float, tolerance: float) -> bool:
    return abs(await read() - target) < tolerance


async def _near_xy(read, north: float, east: float, tolerance: float) -> bool:
    n, e = await read()
    return abs(n - north) < tolerance and abs(e - east) < tolerance


async def _mode_is(telem, mode) -> bool:
    return await telem.flight_mode() == mode


async def _landed(telem) -> bool:
    return await telem.landed_state() == LandedState.ON_GROUND


async def _not(read) -> bool:
    return not await read()


def test_mavsdk_flies_a_full_mission(tmp_path):
    procs = start_processes(tmp_path)
    try:
        steps = asyncio.run(_fly(procs.gcs_port))
    finally:
        procs.stop()
    assert steps == ["healthy", "armed", "took off", "holding", "offboard there and back",
                     "landed and disarmed"]
