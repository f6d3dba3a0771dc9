"""RC as a ground tool sends it, in the ArduPilot flavour (autopilot/commander/rc.py): the
override rules, MANUAL_CONTROL onto the channels, the sticks, the mode switch's bands
and the radio failsafe, through the real server on a loopback UDP link with the link
clock in the test's hands."""

from __future__ import annotations

import numpy as np
import pytest

from autopilot.commander.rc import (
    CHANNELS,
    IGNORE,
    RADIO_OVERRIDE_TIMEOUT_S,
    SWITCH_DEBOUNCE_S,
    switch_position,
)
from autopilot.flight_tasks.sticks import climb_stick, thrust_fraction
from autopilot.parameters import default_parameters
from contracts.modes import FlightMode
from tests.mavlink_station import ACCEPTED, T0, M, Station, air, texts

DEFAULTS = default_parameters()
SET_MODE, CUSTOM = M.MAV_CMD_DO_SET_MODE, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
ALT_HOLD, STABILIZE = 2, 0
EPS = 0.001
CENTRE = (1500, 1500, 1500, 1500)


@pytest.fixture
def copter():
    s = Station(flavour="ardupilot")
    s.state_up()
    yield s
    s.close()


def override(client, *pwm: int, high: tuple[int, ...] = ()) -> list:
    """RC_CHANNELS_OVERRIDE: ``pwm`` on channels 1.., IGNORE on the rest of 1-8; ``high``
    channels 9-18 (0 elsewhere: ignored). Returns what came back (texts)."""
    low = [*pwm, *[IGNORE] * (8 - len(pwm))]
    rest = [*high, *[0] * (10 - len(high))]
    client.send(M.MAVLink_rc_channels_override_message(1, 1, *low, *rest))
    return client.sync()


def at(s: Station, t: float) -> None:
    s.service(t)
    s.client.sync()


def in_alt_hold(s: Station, throttle: int = 1500) -> None:
    """Flying, sticks centred, in ALT_HOLD."""
    s.flying()
    override(s.client, 1500, 1500, throttle, 1500)
    assert s.client.result(SET_MODE, CUSTOM, ALT_HOLD)[0] == ACCEPTED
    assert s.vehicle.mode is FlightMode.ALTCTL


# -- the override rules ----------------------------------------------------------------------
def test_channels_set_ignored_and_released_as_ardupilot_reads_them(copter):
    v = copter.vehicle
    assert v.rc_channels_pwm == (0,) * CHANNELS
    override(copter.client, 1100, 1200, 1300, 1400, 1500, 1600, 1700, 1800,
             high=(1900, 2000, 1000))
    assert v.rc_channels_pwm == (1100, 1200, 1300, 1400, 1500, 1600, 1700, 1800,
                                 1900, 2000, 1000, *[0] * 7)
    # 65535 leaves 1-8 alone, 0 releases them; on 9-18 0 leaves, 65534 releases.
    override(copter.client, IGNORE, 0, 1350, high=(0, 65534, IGNORE))
    assert v.rc_channels_pwm == (1100, 0, 1350, 1400, 1500, 1600, 1700, 1800,
                                 1900, 0, 1000, *[0] * 7)


def test_only_sysid_mygcs_overrides(copter):
    other = copter.new_client(sysid=254)
    assert texts(override(other, *CENTRE)) == []
    assert copter.vehicle.rc_channels_pwm[:4] == (0, 0, 0, 0)
    assert copter.vehicle.links.gcs_heard_s is None
    override(copter.client, *CENTRE)  # the GCS's frame is its heartbeat too
    assert copter.vehicle.links.gcs_heard_s == T0
    override(copter.client, 0, 0, 0, 0)
    copter.vehicle.set_parameter("SYSID_MYGCS", 254)
    override(other, *CENTRE)
    assert copter.vehicle.rc_channels_pwm[:4] == CENTRE
    override(copter.client, 1000, 1000, 1000, 1000)  # 255 is no longer the GCS
    assert copter.vehicle.rc_channels_pwm[:4] == CENTRE


@pytest.mark.parametrize("pwm, said", [
    ((1500, 2300), "setpoint refused: RC override channel 2: 2300 is outside [800, 2200] us"),
    ((799,), "setpoint refused: RC override channel 1: 799 is outside [800, 2200] us")])
def test_a_pwm_off_the_rc_range_refuses_the_whole_override(copter, pwm, said):
    override(copter.client, 1400, 1400, 1400)
    assert texts(override(copter.client, *pwm)) == [said]
    assert copter.vehicle.rc_channels_pwm[:3] == (1400, 1400, 1400)


def test_an_override_expires_rc_override_time_after_its_last_frame(copter):
    v = copter.vehicle
    override(copter.client, *CENTRE)
    at(copter, T0 + 2.0)
    override(copter.client, IGNORE, IGNORE, 1600)  # only the throttle renewed
    at(copter, T0 + DEFAULTS["RC_OVERRIDE_TIME"] - EPS)
    assert v.rc_channels_pwm[:4] == (1500, 1500, 1600, 1500)
    at(copter, T0 + DEFAULTS["RC_OVERRIDE_TIME"])
    assert v.rc_channels_pwm[:4] == (0, 0, 1600, 0)
    at(copter, T0 + 2.0 + DEFAULTS["RC_OVERRIDE_TIME"])
    assert v.rc_channels_pwm[:4] == (0, 0, 0, 0)


def test_a_negative_rc_override_time_never_expires(copter):
    copter.vehicle.set_parameter("RC_OVERRIDE_TIME", -1)
    override(copter.client, *CENTRE)
    at(copter, T0 + 1000.0)
    assert copter.vehicle.rc_channels_pwm[:4] == CENTRE


def test_the_px4_flavour_takes_no_rc_override(station):
    assert "RC_CHANNELS_OVERRIDE" not in station.server.handlers
    assert station.vehicle.rc_channels_pwm == (0,) * CHANNELS


# -- MANUAL_CONTROL onto the channels -------------------------------------------------------
def test_manual_control_overrides_channels_1_to_4_as_copter_maps_it(copter):
    v = copter.vehicle
    # x forward 1000 -> pitch 1000 (reversed), y -1000 -> roll 1000, z 0 -> 1000, r 500.
    copter.client.send(M.MAVLink_manual_control_message(1, 1000, -1000, 0, 500, 0))
    copter.client.sync()
    assert v.rc_channels_pwm[:5] == (1000, 1000, 1000, 1750, 0)
    copter.client.send(M.MAVLink_manual_control_message(1, -400, 200, 1000, 0x7FFF, 0))
    copter.client.sync()
    assert v.rc_channels_pwm[:4] == (1600, 1700, 2000, 0)  # INT16_MAX released yaw
    copter.client.send(M.MAVLink_manual_control_message(2, 0, 0, 500, 0, 0))  # not us
    assert texts(copter.client.sync()) == []
    assert v.rc_channels_pwm[:4] == (1600, 1700, 2000, 0)
    copter.client.send(M.MAVLink_manual_control_message(1, 0, 0, -1, 0, 0))
    assert texts(copter.client.sync()) == [
        "setpoint refused: manual control z -1 is outside [0, 1000]"]
    assert v.rc_channels_pwm[:4] == (1600, 1700, 2000, 0)


# -- the sticks --------------------------------------------------------------------------------
def test_the_channels_are_the_sticks_pitch_low_forward(copter):
    in_alt_hold(copter)
    override(copter.client, 1750, 1000, 1500, 1250)
    at(copter, T0 + 0.1)
    s = copter.vehicle.state.sticks
    assert (s.right, s.forward, s.yaw) == (0.5, 1.0, -0.5)


@pytest.mark.parametrize("throttle, climb_mps", [
    (1500, 0.0), (1600, 0.0), (1400, 0.0),  # within THR_DZ 100 of mid: hold
    (2000, DEFAULTS["MPC_Z_VEL_MAX_UP"]), (1000, -DEFAULTS["MPC_Z_VEL_MAX_DN"]),
    # 1700: 100 of the 400 above the deadzone, through PX4's expo 0.6.
    (1700, (0.4 * 0.25 + 0.6 * 0.25**3) * DEFAULTS["MPC_Z_VEL_MAX_UP"])])
def test_alt_hold_climbs_with_copters_throttle_deadzone(copter, throttle, climb_mps):
    in_alt_hold(copter)
    override(copter.client, 1500, 1500, throttle, 1500)
    at(copter, T0 + 0.1)
    assert climb_stick(copter.vehicle.state.sticks.throttle, copter.vehicle.parameters) == \
        pytest.approx(climb_mps, abs=1e-9)


def test_stabilize_throttle_has_no_deadzone(copter):
    copter.flying()
    override(copter.client, 1500, 1500, 1600, 1500)
    assert copter.client.result(SET_MODE, CUSTOM, STABILIZE)[0] == ACCEPTED
    at(copter, T0 + 0.1)
    v = copter.vehicle
    hover = v.state.hover_fraction
    assert v.state.sticks.throttle == pytest.approx(0.6)
    assert thrust_fraction(v.state.sticks.throttle, hover) == pytest.approx(
        hover + (1 - hover) * 0.2)


def test_alt_hold_needs_the_throttle_channel(copter):
    copter.flying()
    result, said = copter.client.result(SET_MODE, CUSTOM, ALT_HOLD)
    assert (result, said) == (M.MAV_RESULT_FAILED, [
        "Mode change to ALT_HOLD failed: altctl denied: no manual control input"])
    override(copter.client, IGNORE, IGNORE, 1500)
    assert copter.client.result(SET_MODE, CUSTOM, ALT_HOLD)[0] == ACCEPTED


def test_loiter_flies_the_sticks_and_holds_when_they_centre(copter):
    in_alt_hold(copter)
    v = copter.vehicle
    assert copter.client.result(SET_MODE, CUSTOM, 5)[0] == ACCEPTED  # LOITER
    v.step(0.02, air())
    held = v.setpoint.position_ned_m.copy()
    assert v.mode is FlightMode.HOLD and np.all(np.isfinite(held))
    override(copter.client, 1500, 1000, 1500, 1500)  # pitch forward, full
    at(copter, T0 + 0.1)
    v.step(0.03, air())
    assert v.setpoint.velocity_ned_mps[:2] == pytest.approx([DEFAULTS["MPC_VEL_MANUAL"], 0])
    assert np.all(np.isnan(v.setpoint.position_ned_m[:2]))
    assert v.setpoint.position_ned_m[2] == held[2]  # the throttle centred: altitude held
    override(copter.client, *CENTRE)
    at(copter, T0 + 0.2)
    v.step(0.04, air())
    assert np.all(np.isfinite(v.setpoint.position_ned_m[:2]))  # where it can stop
    assert np.all(np.isnan(v.setpoint.velocity_ned_mps[:2]))


# -- the mode switch ---------------------------------------------------------------------------
@pytest.mark.parametrize("pwm, position", [
    (901, 0), (1230, 0), (1231, 1), (1360, 1), (1361, 2), (1490, 2), (1491, 3),
    (1620, 3), (1621, 4), (1749, 4), (1750, 5), (2199, 5), (900, None), (2200, None)])
def test_the_mode_switch_bands_are_copters(pwm, position):
    assert switch_position(pwm) == position


def test_a_held_band_change_on_fltmode_ch_selects_fltmode_n(copter):
    v = copter.vehicle
    copter.flying()
    override(copter.client, *CENTRE, 1300)  # position 2 (LAND): where the switch is
    at(copter, T0 + 0.5)
    assert v.mode is FlightMode.GUIDED  # the first position seen changes nothing
    override(copter.client, *CENTRE, 1800)  # position 6: FLTMODE6 0 STABILIZE
    at(copter, T0 + 0.5 + SWITCH_DEBOUNCE_S - EPS)
    assert v.mode is FlightMode.GUIDED
    at(copter, T0 + 0.5 + SWITCH_DEBOUNCE_S)
    assert v.mode is FlightMode.STABILIZED
    # A mode set otherwise stays while the switch stays in its band.
    assert copter.client.result(SET_MODE, CUSTOM, ALT_HOLD)[0] == ACCEPTED
    override(copter.client, *CENTRE, 1900)
    at(copter, T0 + 1.2)
    assert v.mode is FlightMode.ALTCTL
    copter.vehicle.set_parameter("FLTMODE5", 9)  # LAND
    override(copter.client, *CENTRE, 1700)
    at(copter, T0 + 1.3)
    at(copter, T0 + 1.3 + SWITCH_DEBOUNCE_S)
    assert v.mode is FlightMode.LAND


def test_a_switch_flicked_shorter_than_the_debounce_changes_nothing(copter):
    v = copter.vehicle
    copter.flying()
    override(copter.client, *CENTRE, 1000)
    at(copter, T0 + 0.3)
    override(copter.client, *CENTRE, 2000)
    at(copter, T0 + 0.4)
    override(copter.client, *CENTRE, 1000)
    at(copter, T0 + 0.9)
    assert v.mode is FlightMode.GUIDED


def test_a_refused_switch_position_is_said(copter):
    v = copter.vehicle
    override(copter.client, *CENTRE, 1000)  # disarmed on the ground
    at(copter, T0 + 0.5)
    override(copter.client, *CENTRE, 1700)  # FLTMODE5 5: LOITER
    at(copter, T0 + 0.6)
    v.set_parameter("FLTMODE5", 1)  # ACRO: not built
    override(copter.client, *CENTRE, 1700)
    copter.service(T0 + 0.6 + SWITCH_DEBOUNCE_S)
    assert texts(copter.client.sync()) == ["mode switch position 5: mode 1 is not built"]
    assert v.mode is FlightMode.STABILIZED  # where it booted


# -- the radio failsafe -------------------------------------------------------------------------
def test_overrides_stopping_for_a_second_in_flight_is_the_radio_failsafe(copter):
    in_alt_hold(copter)
    at(copter, T0 + RADIO_OVERRIDE_TIMEOUT_S - EPS)
    assert copter.vehicle.mode is FlightMode.ALTCTL
    copter.service(T0 + RADIO_OVERRIDE_TIMEOUT_S)
    assert texts(copter.client.sync()) == ["Radio Failsafe: rtl"]  # a Copter mode change
    # says nothing more: its HEARTBEAT shows the mode
    assert copter.vehicle.mode is FlightMode.RTL and copter.vehicle.failsafe == \
        "Radio Failsafe"
    override(copter.client, *CENTRE)
    copter.service(T0 + RADIO_OVERRIDE_TIMEOUT_S + 0.5)
    assert texts(copter.client.sync()) == ["Radio Failsafe Cleared"]
    assert copter.vehicle.mode is FlightMode.RTL  # Copter does not go back


@pytest.mark.parametrize("fs_thr_enable, mode", [(3, FlightMode.LAND), (7, FlightMode.LAND),
                                                 (4, FlightMode.RTL), (0, FlightMode.ALTCTL)])
def test_fs_thr_enable_chooses_the_action(copter, fs_thr_enable, mode):
    copter.vehicle.set_parameter("FS_THR_ENABLE", fs_thr_enable)
    in_alt_hold(copter)
    at(copter, T0 + 2.0)
    assert copter.vehicle.mode is mode


def test_a_throttle_below_fs_thr_value_three_frames_running_is_the_radio_failsafe(copter):
    in_alt_hold(copter)
    for _ in range(2):
        override(copter.client, *CENTRE[:2], 970)
    copter.service()
    assert copter.vehicle.mode is FlightMode.ALTCTL
    override(copter.client, *CENTRE[:2], 970)
    copter.service()
    assert copter.vehicle.mode is FlightMode.RTL


def test_on_the_ground_the_radio_failsafe_disarms(copter):
    in_alt_hold(copter)
    copter.state_up(air(0.0), 0.02)  # touched down
    copter.vehicle.land_detector.landed = True
    copter.service(T0 + 1.5)
    assert not copter.vehicle.armed
    assert copter.vehicle.failsafe == "Radio Failsafe"


def test_released_overrides_end_the_radio_without_a_failsafe(copter):
    in_alt_hold(copter)
    override(copter.client, 0, 0, 0, 0)
    at(copter, T0 + 5.0)
    assert copter.vehicle.failsafe is None and copter.vehicle.armed
    assert copter.vehicle.state.sticks.throttle == 0.5  # centred: holds
