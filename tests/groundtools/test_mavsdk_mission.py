"""MAVSDK 4.x's mission and geofence plugins against the real processes: upload a mission
(waypoints with a speed, a loiter and a yaw), download it back the same, clear it; upload
a geofence (an inclusion polygon and an exclusion circle) and download it."""

from __future__ import annotations

import asyncio

import pytest
from mavsdk import log_subscribe
from mavsdk.asyncio.plugins.geofence import (
    Circle,
    FenceType,
    GeofenceAsync,
    GeofenceData,
    Point,
    Polygon,
)
from mavsdk.asyncio.plugins.mission import MissionAsync, MissionPlan

from tests.harness import start_processes
from tests.mavsdk_helpers import autopilot_on, mission_item

pytestmark = [pytest.mark.process, pytest.mark.groundtool]

log_subscribe(lambda level, text, file, line: level.value < 2)  # warnings and errors only

HOME = (47.397742, 8.545594)


async def _session(port: int) -> dict:
    out = {}
    async with autopilot_on(port) as system:
        mission, fence = MissionAsync(system), GeofenceAsync(system)
        plan = MissionPlan([mission_item(0, 0, 5.0, speed_mps=3.0),
                            mission_item(20, 0, 5.0, loiter_s=2.0),
                            mission_item(20, 20, 8.0, yaw_deg=90.0)])
        await mission.upload_mission(plan)
        out["mission"] = (await mission.download_mission()).mission_items
        await mission.clear_mission()
        out["cleared"] = (await mission.download_mission()).mission_items
        square = [Point(HOME[0] + n / 111_320.0, HOME[1] + e / 75_000.0)
                  for n, e in ((50, 50), (50, -50), (-50, -50), (-50, 50))]
        await fence.upload_geofence(GeofenceData(
            [Polygon(square, FenceType.INCLUSION)],
            [Circle(Point(HOME[0] + 10 / 111_320.0, HOME[1]), 5.0, FenceType.EXCLUSION)]))
        out["fence"] = await fence.download_geofence()
        out["plan"] = plan.mission_items
    return out


def test_mavsdk_uploads_downloads_and_clears_a_mission_and_a_geofence(tmp_path):
    procs = start_processes(tmp_path)
    try:
        got = asyncio.run(asyncio.wait_for(_session(procs.gcs_port), 90))
    finally:
        procs.stop()
    sent, back = got["plan"], got["mission"]
    assert len(back) == 3
    for a, b in zip(sent, back, strict=True):
        assert abs(a.latitude_deg - b.latitude_deg) < 1e-7
        assert abs(a.longitude_deg - b.longitude_deg) < 1e-7
        assert abs(a.relative_altitude_m - b.relative_altitude_m) < 1e-4
    assert back[0].speed_m_s == 3.0  # a DO_CHANGE_SPEED went up and came back
    assert back[1].loiter_time_s == 2.0
    assert back[2].yaw_deg == 90.0
    assert got["cleared"] == []
    fence = got["fence"]
    assert len(fence.polygons) == 1 and len(fence.polygons[0].points) == 4
    assert fence.polygons[0].fence_type == FenceType.INCLUSION
    assert len(fence.circles) == 1 and fence.circles[0].radius == 5.0
