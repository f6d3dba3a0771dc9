"""What the MAVSDK tests share: connecting as a ground station, waiting for a condition,
and mission items placed in metres from home."""

from __future__ import annotations

import asyncio
import contextlib
import inspect
import math
import time
from collections.abc import AsyncIterator

from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
from mavsdk.asyncio.plugins.mission import MissionItem

from contracts.frames import DEFAULT_HOME


@contextlib.asynccontextmanager
async def autopilot_on(port: int) -> AsyncIterator:
    """MAVSDK as a ground station listening on ``port``, and the first autopilot it hears
    (its ``System``)."""
    mavsdk = Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION))
    async with mavsdk:
        await mavsdk.add_any_connection(f"udpin://127.0.0.1:{port}")
        system = await mavsdk.first_autopilot(timeout_s=30.0)
        assert system is not None, "no autopilot heard"
        yield system


async def until(check, timeout_s: float, what: str) -> None:
    """Poll ``check()`` (plain or awaitable) until it is true; fail after ``timeout_s``."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        result = check()
        if inspect.isawaitable(result):
            result = await result
        if result:
            return
        await asyncio.sleep(0.05)
    raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")


def mission_item(north_m: float, east_m: float, alt_m: float, speed_mps: float = math.nan,
                 loiter_s: float = math.nan, yaw_deg: float = math.nan) -> MissionItem:
    """A MAVSDK mission item ``north_m``, ``east_m`` from home, ``alt_m`` above it; it flies
    through unless it loiters."""
    lat, lon, _ = DEFAULT_HOME.geodetic_from_ned(north_m, east_m, 0.0)
    return MissionItem(lat, lon, alt_m, speed_mps, math.isnan(loiter_s), math.nan, math.nan,
                       MissionItem.CameraAction.NONE, loiter_s, math.nan, 1.0, yaw_deg,
                       math.nan, MissionItem.VehicleAction.NONE)


async def inject_enabled(system, param, unit, kind, instance: int):
    """``inject`` with SYS_FAILURE_EN 1 on the vehicle, through a failure plugin made once
    the parameter reads 1. MAVSDK's failure plugin keeps its own copy of the parameter:
    one read when it starts, then a subscription that hears only a PARAM_VALUE arriving
    while no parameter request is waiting (the answer to a set or a get goes to that
    request alone; MAVSDK 4.1's parameter client). After a set, an older plugin hears the
    new value only from the vehicle's second, broadcast copy, and loses that copy for good
    if another request is queued first (DISABLED with nothing sent, for all 5 s of
    retries, beside a busy neighbour). A new plugin reads the value itself."""
    from mavsdk.asyncio.plugins.failure import FailureAsync

    assert await param.get_param_int("SYS_FAILURE_EN") == 1
    failure = FailureAsync(system)
    try:
        return await failure.inject(unit, kind, instance)
    finally:
        failure.destroy()
