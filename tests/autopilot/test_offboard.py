"""Offboard setpoint mapping (autopilot/mavlink/offboard.py): type_mask and every frame PX4
takes."""

from __future__ import annotations

import math

import numpy as np
import pytest

from autopilot.mavlink.offboard import (
    ACCEL_BITS,
    FORCE_SET,
    POSITION_BITS,
    VELOCITY_BITS,
    YAW_IGNORE,
    YAW_RATE_IGNORE,
    global_setpoint,
    local_setpoint,
)
from autopilot.navigator.home import Places
from autopilot.refusal import RefusedError
from contracts.frames import DEFAULT_HOME
from contracts.mavlink import mavlink

HERE = np.array([10.0, -4.0, -3.0])
EAST = math.pi / 2  # heading east: forward is +east, right is -north (south)
ALL_POSITION = sum(POSITION_BITS)
ALL_VELOCITY = sum(VELOCITY_BITS)
ALL_ACCEL = sum(ACCEL_BITS)
POSITION_ONLY = ALL_VELOCITY | ALL_ACCEL | YAW_RATE_IGNORE  # MAVSDK's 0x9F8 keeps yaw
VELOCITY_ONLY = ALL_POSITION | ALL_ACCEL | YAW_RATE_IGNORE
BODY_VELOCITY = ALL_POSITION | ALL_ACCEL | YAW_IGNORE  # MAVSDK set_velocity_body

AT_HOME = Places.at(DEFAULT_HOME)  # home at the local origin


def local(frame, mask, position=(1.0, 2.0, -5.0), velocity=(0.5, 1.0, -0.2),
          accel=(0.1, 0.2, 0.3), yaw=0.3, yaw_rate=0.1, heading=EAST):
    return local_setpoint(frame, mask, position, velocity, accel, yaw, yaw_rate, HERE, heading)


def test_mavsdk_position_mask_is_0x9f8() -> None:
    assert POSITION_ONLY == 0x9F8


def test_local_ned_is_taken_as_it_is() -> None:
    sp = local(mavlink.MAV_FRAME_LOCAL_NED, POSITION_ONLY)
    assert np.array_equal(sp.position_ned_m, [1.0, 2.0, -5.0])
    assert np.all(np.isnan(sp.velocity_ned_mps)) and np.all(np.isnan(sp.accel_ned_mps2))
    assert sp.yaw_rad == 0.3 and math.isnan(sp.yaw_rate_rad_s)


def test_local_offset_is_added_to_the_vehicle_position() -> None:
    sp = local(mavlink.MAV_FRAME_LOCAL_OFFSET_NED, 0)
    assert np.allclose(sp.position_ned_m, HERE + (1.0, 2.0, -5.0))
    assert np.allclose(sp.velocity_ned_mps, (0.5, 1.0, -0.2))  # NED vectors stay NED


@pytest.mark.parametrize("frame", [mavlink.MAV_FRAME_BODY_NED, mavlink.MAV_FRAME_BODY_OFFSET_NED,
                                   mavlink.MAV_FRAME_BODY_FRD, mavlink.MAV_FRAME_LOCAL_FRD])
def test_body_frames_turn_vectors_by_the_heading(frame) -> None:
    sp = local(frame, BODY_VELOCITY, velocity=(2.0, 1.0, -0.5), yaw_rate=0.4)
    # Forward 2 m/s and right 1 m/s while heading east: east 2, south 1; down unchanged.
    assert np.allclose(sp.velocity_ned_mps, (-1.0, 2.0, -0.5))
    assert math.isnan(sp.yaw_rad) and sp.yaw_rate_rad_s == 0.4
    assert np.all(np.isnan(sp.position_ned_m))


def test_body_positions_as_mavlink_defines_them() -> None:
    offset = (3.0, 1.0, -1.0)  # forward 3, right 1, up 1
    body_ned = local(mavlink.MAV_FRAME_BODY_NED, POSITION_ONLY, position=offset)
    assert np.allclose(body_ned.position_ned_m, offset)  # BODY_NED: positions are LOCAL_NED
    for frame in (mavlink.MAV_FRAME_BODY_OFFSET_NED, mavlink.MAV_FRAME_BODY_FRD):
        sp = local(frame, POSITION_ONLY, position=offset)
        assert np.allclose(sp.position_ned_m, HERE + (-1.0, 3.0, -1.0))
    frd = local(mavlink.MAV_FRAME_LOCAL_FRD, POSITION_ONLY, position=offset)
    assert np.allclose(frd.position_ned_m, (-1.0, 3.0, -1.0))  # from home, turned


def test_mask_leaves_groups_out_and_yaw_wins_over_its_rate() -> None:
    sp = local(mavlink.MAV_FRAME_LOCAL_NED, ALL_POSITION | ALL_ACCEL)
    assert np.all(np.isnan(sp.position_ned_m))
    assert np.allclose(sp.velocity_ned_mps, (0.5, 1.0, -0.2))
    assert sp.yaw_rad == 0.3 and math.isnan(sp.yaw_rate_rad_s)
    no_yaw = local(mavlink.MAV_FRAME_LOCAL_NED, YAW_IGNORE | YAW_RATE_IGNORE)
    assert math.isnan(no_yaw.yaw_rad) and math.isnan(no_yaw.yaw_rate_rad_s)
    xy_only = local(mavlink.MAV_FRAME_LOCAL_NED, POSITION_BITS[2] | ALL_ACCEL,
                    velocity=(0.0, 0.0, 1.0))
    assert np.isnan(xy_only.position_ned_m[2]) and xy_only.velocity_ned_mps[2] == 1.0


@pytest.mark.parametrize("field, value", [("position", (math.nan, 0.0, 0.0)),
                                          ("velocity", (0.0, math.inf, 0.0)),
                                          ("accel", (0.0, 0.0, -math.inf)),
                                          ("yaw", math.nan)])
def test_used_fields_must_be_finite(field, value) -> None:
    with pytest.raises(RefusedError, match="NaN or infinity"):
        local(mavlink.MAV_FRAME_LOCAL_NED, YAW_RATE_IGNORE, **{field: value})
    # ... while a left-out field may hold anything.
    local(mavlink.MAV_FRAME_LOCAL_NED, ALL_POSITION | ALL_VELOCITY | ALL_ACCEL | YAW_IGNORE
          | YAW_RATE_IGNORE, **{field: value})


def test_unsupported_frames_and_force_setpoints_are_refused() -> None:
    with pytest.raises(RefusedError, match="frame 21"):
        local(mavlink.MAV_FRAME_LOCAL_FLU, POSITION_ONLY)
    with pytest.raises(RefusedError, match="force"):
        local(mavlink.MAV_FRAME_LOCAL_NED, FORCE_SET)


def test_the_force_bit_with_every_acceleration_masked_is_a_position_setpoint() -> None:
    """DroneKit's examples send 0x0FF8: position only, with the force bit set."""
    setpoint = local(mavlink.MAV_FRAME_LOCAL_NED, 0x0FF8, position=(1.0, 2.0, -3.0))
    assert list(setpoint.position_ned_m) == [1.0, 2.0, -3.0]
    with pytest.raises(RefusedError, match="force"):
        local(mavlink.MAV_FRAME_LOCAL_NED, 0x0FF8 & ~ALL_ACCEL)


def test_global_setpoints_in_a_terrain_frame_are_refused() -> None:
    with pytest.raises(RefusedError, match="terrain"):
        global_setpoint(AT_HOME, mavlink.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT, POSITION_ONLY,
                        0, 0, 5.0, (0, 0, 0), (0, 0, 0), 0.0, 0.0)


@pytest.mark.parametrize("frame, relative", [(mavlink.MAV_FRAME_GLOBAL_INT, False),
                                             (mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, True),
                                             (mavlink.MAV_FRAME_GLOBAL, False),
                                             (mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT, True)])
def test_global_setpoints_land_where_geodetic_from_ned_puts_them(frame, relative) -> None:
    target = (35.0, -12.0, -6.0)
    lat, lon, amsl = DEFAULT_HOME.geodetic_from_ned(*target)
    alt = amsl - DEFAULT_HOME.alt_amsl_m if relative else amsl
    sp = global_setpoint(AT_HOME, frame, POSITION_ONLY, round(lat * 1e7),
                         round(lon * 1e7), alt, (0, 0, 0), (0, 0, 0), 1.0, 0.0)
    assert np.allclose(sp.position_ned_m, target, atol=0.02)  # 1e-7 deg is ~1 cm
    assert sp.yaw_rad == 1.0


def test_global_setpoints_off_the_earth_are_refused() -> None:
    with pytest.raises(RefusedError, match="not on Earth"):
        global_setpoint(AT_HOME, mavlink.MAV_FRAME_GLOBAL_INT, POSITION_ONLY,
                        950_000_000, 0, 500.0, (0, 0, 0), (0, 0, 0), 0.0, 0.0)
