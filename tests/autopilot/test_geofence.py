"""The geofence: zones from an uploaded fence, PX4's distance limits, and GF_ACTION when a
flight crosses out (in one process, on sim time)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from autopilot.navigator.geofence import breach, zones_from_items
from autopilot.navigator.mission_store import FENCE, MissionItem
from contracts.frames import DEFAULT_HOME
from contracts.mavlink import mavlink
from contracts.modes import FlightMode
from tests.flight import Flight, position_setpoint

M = mavlink


def _at(seq: int, command: int, north: float, east: float, param1: float) -> MissionItem:
    lat, lon, _ = DEFAULT_HOME.geodetic_from_ned(north, east, 0.0)
    return MissionItem(seq, M.MAV_FRAME_GLOBAL_INT, command, 0, 1, (param1, 0.0, 0.0, 0.0),
                       round(lat * 1e7), round(lon * 1e7), 0.0, FENCE)


def square_with_a_hole() -> tuple[MissionItem, ...]:
    """A 40 m square around home, and a 3 m circle excluded 10 m north."""
    corners = ((20, 20), (20, -20), (-20, -20), (-20, 20))
    items = [_at(i, M.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION, n, e, 4.0)
             for i, (n, e) in enumerate(corners)]
    items.append(_at(4, M.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION, 10.0, 0.0, 3.0))
    return tuple(items)


@pytest.mark.parametrize("north, east, reason", [
    (0.0, 0.0, None), (15.0, -15.0, None), (25.0, 0.0, "outside the inclusion fence"),
    (0.0, -20.5, "outside the inclusion fence"), (11.0, 1.0, "inside an exclusion zone"),
    (10.0, 3.5, None)])
def test_a_position_is_inside_or_says_which_zone_it_breaks(north, east, reason):
    zones = zones_from_items(square_with_a_hole(), DEFAULT_HOME)
    assert breach(np.array([north, east, -2.0]), zones, 0.0, 0.0) == reason


def test_the_distance_limits_and_zero_meaning_off():
    assert breach(np.array([30.0, 40.0, -2.0]), (), 0.0, 0.0) is None
    assert breach(np.array([30.0, 40.0, -2.0]), (), 45.0, 0.0) == \
        "50.0 m from home, beyond 45 m"
    assert breach(np.array([0.0, 0.0, -12.0]), (), 0.0, 10.0) == "12.0 m up, above 10 m"


def _fly_north(flight: Flight, north_m: float, duration_s: float) -> float | None:
    """Offboard to ``north_m`` at 2.5 m; the sim time the mode left OFFBOARD (or None)."""
    flight.take_off(2.5)
    setpoint = position_setpoint(north_m, 0.0, -2.5)
    flight.start_offboard(setpoint)
    for _ in range(round(duration_s / 0.05)):
        flight.stream(setpoint, 0.05)
        if flight.vehicle.mode != FlightMode.OFFBOARD:
            return flight.t_s
    return None


def _crossed_s(flight: Flight, inside) -> float:
    log = flight.log
    outside = np.array([not inside(row[1], row[2]) for row in log])
    return float(log[np.argmax(outside), 0])


def test_crossing_the_distance_limit_holds_within_a_second_and_says_so():
    flight = Flight(controller="pid", parameters={"GF_MAX_HOR_DIST": 8.0, "GF_ACTION": 2.0})
    switched = _fly_north(flight, 30.0, 15.0)
    crossed = _crossed_s(flight, lambda n, e: math.hypot(n, e) <= 8.0)
    assert switched is not None and 0.0 <= switched - crossed <= 0.06  # the next sample
    v = flight.vehicle
    assert v.mode == FlightMode.HOLD and v.failsafe.startswith("geofence: ")
    assert any(t.startswith("geofence: 8.0") and t.endswith(": hold") for _s, t in v.messages)
    flight.run(5.0)
    # It brakes (MPC_ACC_HOR, jerk-limited) from about 5 m/s and holds where it stopped.
    held = flight.since(flight.t_s - 2.0)[:, 1]
    assert np.ptp(held) < 0.05 and 8.0 < held[-1] < 16.0


def test_a_warning_only_says_so_and_flies_on():
    flight = Flight(controller="pid", parameters={"GF_MAX_HOR_DIST": 8.0, "GF_ACTION": 1.0})
    assert _fly_north(flight, 30.0, 15.0) is None
    v = flight.vehicle
    assert v.mode == FlightMode.OFFBOARD and v.failsafe is None
    assert [t for _s, t in v.messages if t.startswith("geofence:")] == \
        ["geofence: 8.0 m from home, beyond 8 m"]
    assert flight.log[-1, 1] == pytest.approx(30.0, abs=0.5)


def test_an_uploaded_exclusion_zone_lands_the_vehicle():
    flight = Flight(controller="pid", parameters={"GF_ACTION": 5.0})
    flight.vehicle.mission.replace(FENCE, square_with_a_hole())
    switched = _fly_north(flight, 15.0, 12.0)
    crossed = _crossed_s(flight, lambda n, e: math.hypot(n - 10.0, e) > 3.0)
    assert switched is not None and 0.0 <= switched - crossed <= 0.06
    v = flight.vehicle
    assert v.mode == FlightMode.LAND
    assert any(t == "geofence: inside an exclusion zone: land" for _s, t in v.messages)
    flight.run(10.0)
    assert not v.armed and flight.log[-1, 3] > -0.05  # landed and disarmed


def test_an_empty_circle_is_no_zone():
    """MAVSDK's geofence plugin sends a circle of radius 0 at 0, 0 when a caller has none."""
    empty = MissionItem(5, M.MAV_FRAME_GLOBAL_INT, M.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION, 0, 1,
                        (0.0, 0.0, 0.0, 0.0), 0, 0, 0.0, FENCE)
    zones = zones_from_items((*square_with_a_hole(), empty), DEFAULT_HOME)
    assert len(zones) == 2  # the square and the hole
    assert breach(np.array([15.0, -15.0, -2.0]), zones, 0.0, 0.0) is None
    assert zones_from_items((empty,), DEFAULT_HOME) == ()
