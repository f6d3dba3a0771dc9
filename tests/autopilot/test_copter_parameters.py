"""The ArduPilot flavour's parameter protocol in process, as Copter SITL answers it
(GCS_Param.cpp, AP_Param::set_float): Copter's names, units and types over the one
internal table, C-cast values, PARAM_VALUE echoed with index -1 on every link after a
set, unknown names ignored without a word. A real UDP socket and a pymavlink client."""

from __future__ import annotations

import math

import pytest

from autopilot.copter_parameters import (
    ARDUPILOT_ONLY,
    COPTER_PARAMETERS,
    ardupilot_parameters,
    cast,
    px4_parameters,
)
from autopilot.mavlink.params import NO_INDEX
from autopilot.parameters import PARAMETERS, default_parameters
from tests.mavlink_station import M, of_type, texts

DEFAULTS = default_parameters()
INT8, INT16, INT32, REAL32 = (M.MAV_PARAM_TYPE_INT8, M.MAV_PARAM_TYPE_INT16,
                              M.MAV_PARAM_TYPE_INT32, M.MAV_PARAM_TYPE_REAL32)
# issue 36's list, FLTMODE* aside (the rc engineer's internal ones)
ISSUE_NAMES = (
    "SYSID_THISMAV", "SYSID_MYGCS", "FS_GCS_ENABLE", "FS_GCS_TIMEOUT", "FS_THR_ENABLE",
    "FS_THR_VALUE", "FS_EKF_THRESH", "FS_EKF_ACTION", "ARMING_CHECK", "DISARM_DELAY",
    "MOT_SPIN_ARM", "MOT_SPIN_MIN", "MOT_SPIN_MAX", "MOT_THST_HOVER", "WPNAV_SPEED",
    "WPNAV_SPEED_UP", "WPNAV_SPEED_DN", "WPNAV_ACCEL", "WPNAV_RADIUS", "LOIT_SPEED",
    "PILOT_SPEED_UP", "PILOT_SPEED_DN", "ANGLE_MAX", "RTL_ALT", "RTL_ALT_FINAL",
    "RTL_LOIT_TIME", "RTL_SPEED", "LAND_SPEED", "CIRCLE_RADIUS", "CIRCLE_RATE",
    "GUID_TIMEOUT",
)


@pytest.fixture
def copter(make_station):
    return make_station(flavour="ardupilot")


def param_set(name: str, value: float, kind: int = REAL32):
    return M.MAVLink_param_set_message(1, 1, name.encode(), value, kind)


def test_the_list_is_copters_names_units_and_types_then_our_own_gains(copter):
    copter.client.send(M.MAVLink_param_request_list_message(1, 1))
    values = of_type(copter.client.sync(), "PARAM_VALUE")
    names = [v.param_id for v in values]
    assert names == [p.name for p in ardupilot_parameters()]
    assert set(ISSUE_NAMES) <= set(names)
    assert {n for n in names if n.startswith(("FENCE_", "FOLL_"))} >= {
        "FENCE_ENABLE", "FENCE_ACTION", "FENCE_ALT_MAX", "FENCE_RADIUS", "FOLL_ENABLE"}
    assert "MPC_XY_CRUISE" not in names and "ATT_LAM" in names and "PID_RATE_P" in names
    assert [v.param_index for v in values] == list(range(len(values)))
    assert {v.param_count for v in values} == {len(values)}
    got = {v.param_id: (v.param_value, v.param_type) for v in values}
    # Copter's units over the internal values; C-cast (not byte-wise) encoding
    assert got["WPNAV_SPEED"] == (pytest.approx(DEFAULTS["MPC_XY_CRUISE"] * 100), REAL32)
    assert got["RTL_ALT"] == (DEFAULTS["RTL_RETURN_ALT"] * 100, INT32)  # 1000 cm
    assert got["ANGLE_MAX"] == (2005.0, INT16)  # 20.05 deg, cast to whole centidegrees
    assert got["LAND_SPEED"] == (70.0, INT16)
    assert got["WPNAV_RADIUS"] == (200.0, REAL32)
    assert got["FS_GCS_ENABLE"] == (7.0, INT8)  # NAV_DLL_ACT 1 hold: brake or land
    assert got["FS_GCS_TIMEOUT"] == (10.0, REAL32)
    assert got["SYSID_MYGCS"] == (255.0, INT16)
    assert got["FENCE_RADIUS"] == (0.0, REAL32) and got["ATT_LAM"][1] == REAL32


def test_cast_rounds_and_clamps_as_ap_param_set_float():
    assert cast("INT16", 2500.4) == 2500 and cast("INT8", 1000) == 127
    assert cast("INT16", -2.995) == -3 and cast("INT32", 0.996) == 1
    assert cast("REAL32", 0.25) == 0.25


@pytest.mark.parametrize("name, sent, kind, internal, value, echoed", [
    ("WPNAV_SPEED", 250.0, REAL32, "MPC_XY_CRUISE", 2.5, 250.0),
    ("RTL_ALT", 2500.0, INT32, "RTL_RETURN_ALT", 25.0, 2500.0),
    ("ANGLE_MAX", 2500.4, REAL32, "MPC_TILTMAX_AIR", 25.0, 2500.0),  # cast, any type sent
    ("ANGLE_MAX", 1999.996, INT8, "MPC_TILTMAX_AIR", 20.0, 2000.0),  # +0.01, truncated
    ("LAND_SPEED", 120.0, INT16, "MPC_LAND_SPEED", 1.2, 120.0),
    ("FS_GCS_ENABLE", 5.0, INT8, "NAV_DLL_ACT", 3.0, 5.0),  # always land
    ("FS_GCS_ENABLE", 1.0, INT8, "NAV_DLL_ACT", 2.0, 1.0),  # RTL
    ("FENCE_ACTION", 2.0, INT8, "GF_ACTION", 5.0, 2.0),  # always land
    ("FENCE_RADIUS", 150.0, REAL32, "GF_MAX_HOR_DIST", 150.0, 150.0),
    ("FS_THR_VALUE", 950.7, REAL32, "FS_THR_VALUE", 950.0, 950.0),  # an ArduPilot-only one
    ("DISARM_DELAY", 5.0, INT8, "COM_DISARM_LAND", 5.0, 5.0),
])
def test_a_set_changes_the_internal_value_and_is_echoed_on_every_link_with_index_minus_1_uint16(
        make_station, name, sent, kind, internal, value, echoed):
    s = make_station(flavour="ardupilot", n_links=2)
    other = s.new_client(1)
    other.heartbeat()
    other.sync()
    s.client.send(param_set(name, sent, kind))
    msgs = s.client.sync()
    assert texts(msgs) == []
    assert s.vehicle.parameters[internal] == pytest.approx(value, rel=1e-12)
    for got in (msgs, other.sync()):
        (echo,) = of_type(got, "PARAM_VALUE")
        assert (echo.param_id, echo.param_value, echo.param_index) == (name, echoed, NO_INDEX)


def test_a_stored_only_parameter_keeps_what_is_set_as_its_type_casts_it(copter):
    copter.client.send(param_set("FENCE_ENABLE", 1.0, INT8))
    copter.client.send(param_set("RTL_ALT_FINAL", 950.7))
    copter.client.send(param_set("FOLL_OFS_X", -3.5))
    copter.client.sync()
    for name in ("FENCE_ENABLE", "RTL_ALT_FINAL", "FOLL_OFS_X"):
        copter.client.send(M.MAVLink_param_request_read_message(1, 1, name.encode(), -1))
    values = of_type(copter.client.sync(), "PARAM_VALUE")
    assert [(v.param_id, v.param_value) for v in values] == [
        ("FENCE_ENABLE", 1.0), ("RTL_ALT_FINAL", 950.0), ("FOLL_OFS_X", -3.5)]
    assert copter.vehicle.parameters == DEFAULTS  # nothing in the vehicle moved


def test_read_by_name_answers_index_minus_1_uint16_by_index_the_index_unknown_nothing(copter):
    third = COPTER_PARAMETERS[2]
    third_value = third.from_internal(DEFAULTS[third.internal]) if third.internal else \
        third.default
    copter.client.send(M.MAVLink_param_request_read_message(1, 1, b"RTL_ALT", -1))
    copter.client.send(M.MAVLink_param_request_read_message(1, 1, b"", 2))
    copter.client.send(M.MAVLink_param_request_read_message(1, 1, b"MPC_XY_CRUISE", -1))
    copter.client.send(M.MAVLink_param_request_read_message(1, 1, b"", 9999))
    msgs = copter.client.sync()
    assert [(v.param_id, v.param_value, v.param_index) for v in of_type(msgs, "PARAM_VALUE")
            ] == [("RTL_ALT", 1000.0, NO_INDEX), (third.name, third_value, 2)]
    assert texts(msgs) == []  # Copter says nothing of a name it does not have


@pytest.mark.parametrize("name", ["NO_SUCH_PARAM", "MPC_XY_CRUISE"])
def test_an_unknown_name_is_ignored_without_a_word_as_copter(copter, name):
    copter.client.send(param_set(name, 3.0))
    msgs = copter.client.sync()
    assert of_type(msgs, "PARAM_VALUE") == [] and texts(msgs) == []
    assert copter.vehicle.parameters == DEFAULTS


@pytest.mark.parametrize("value", [math.nan, math.inf, -math.inf])
def test_a_non_finite_value_changes_nothing_and_the_value_in_force_is_echoed(copter, value):
    copter.client.send(param_set("WPNAV_SPEED", value))
    msgs = copter.client.sync()
    (echo,) = of_type(msgs, "PARAM_VALUE")
    assert (echo.param_id, echo.param_value) == ("WPNAV_SPEED", 500.0)
    assert copter.vehicle.parameters == DEFAULTS


@pytest.mark.parametrize("name, value, said, shown", [
    ("WPNAV_SPEED", 5.0, "Param write denied (WPNAV_SPEED): 5 is outside 50..2000 cm/s",
     500.0),
    ("RTL_ALT", 10.0, "Param write denied (RTL_ALT): 10 is outside 50..50000 cm", 1000.0),
    ("FS_GCS_TIMEOUT", 2.5, "Param write denied (FS_GCS_TIMEOUT): 2.5 is outside 1..300 "
     "s (whole numbers)", 10.0),
    ("FS_GCS_ENABLE", 2.0, "Param write denied (FS_GCS_ENABLE): FS_GCS_ENABLE 2 is not "
     "supported here (one of 0, 1, 5, 7)", 7.0),
    ("FS_GCS_ENABLE", 2.0, "Param write denied (FS_GCS_ENABLE): FS_GCS_ENABLE 2 is not "
     "supported here (one of 0, 1, 5, 7)", 7.0),
])
def test_a_value_the_vehicle_cannot_fly_is_refused_in_copters_units(copter, name, value,
                                                                     said, shown):
    # Copter stores any value its type holds; this vehicle keeps its internal ranges
    # (a documented difference): refused, said, the value in force echoed.
    copter.client.send(param_set(name, value))
    msgs = copter.client.sync()
    assert texts(msgs) == [said]
    (echo,) = of_type(msgs, "PARAM_VALUE")
    assert (echo.param_id, echo.param_value, echo.param_index) == (name, shown, NO_INDEX)
    assert copter.vehicle.parameters == DEFAULTS


def test_the_px4_flavour_lists_the_table_without_the_ardupilot_only_names():
    assert set(ARDUPILOT_ONLY) == {*(f"FLTMODE{i}" for i in range(1, 7)), "FLTMODE_CH",
                                   "SYSID_MYGCS", "RC_OVERRIDE_TIME", "FS_THR_ENABLE",
                                   "FS_THR_VALUE", "THR_DZ"}
    assert px4_parameters() == tuple(s.name for s in PARAMETERS
                                     if s.name not in ARDUPILOT_ONLY)
    listed = {p.name for p in ardupilot_parameters()}
    assert {n for n in ARDUPILOT_ONLY if n in DEFAULTS} <= listed
