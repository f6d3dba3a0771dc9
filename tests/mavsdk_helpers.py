"""What the MAVSDK tests share: waiting for a condition, and mission items placed in
metres from home."""

from __future__ import annotations

import asyncio
import inspect
import math
import time

from mavsdk.asyncio.plugins.mission import MissionItem

from contracts.frames import DEFAULT_HOME


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
