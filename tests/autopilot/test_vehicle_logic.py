"""The vehicle's logic in process, on injected clocks: arming, modes, take-off, landing,
setpoints, failsafes and the STATUSTEXT they queue.

:class:`autopilot.commander.commander.Commander` takes its times as arguments: ``sim_t_s`` for the
control path and ``link_t_s`` for what ground tools do. So every timeout here is tested
on both sides of its threshold (1 ms before and 1 ms after), with the number taken from
the parameter table, and flights close the loop with the real controller and the real
plant (``sitl/plant.py``) in sim time: deterministic, a fraction of a second each. The
process tests (test_vehicle_mavlink.py) only need to show the same logic is wired up.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from autopilot.commander.commander import Commander
from autopilot.commander.failsafe import Stream
from autopilot.commander.land_detector import LANDED_ALTITUDE_M, LANDED_SPEED_MPS
from autopilot.control.factory import make_controller
from autopilot.flight_tasks.shaping import Setpoint
from autopilot.flight_tasks.takeoff import TAKEOFF_REACHED_M
from autopilot.parameters import default_parameters
from autopilot.refusal import RefusedError
from autopilot.trajectories import Reference
from contracts.airframe import PAPER
from contracts.frames import quat_from_euler
from contracts.modes import FlightMode
from sitl.plant import Plant

PERIOD_S = 0.01
PERIOD_US = 10_000
DEFAULTS = default_parameters()
LINK0 = 1000.0  # the link clock (wall time in the shell) is not the sim clock
EPS = 0.001  # 1 ms either side of a threshold
INFO, NOTICE, WARNING = 6, 5, 4  # MAV_SEVERITY


# -- building blocks -------------------------------------------------------------------
def make_vehicle(controller: str = "pid", flavour: str = "px4",
                 reference: Reference | None = None, models=None, **parameters) -> Commander:
    """A Commander as the autopilot process builds one, with the real controller factory."""
    return Commander(lambda p: make_controller(controller, PAPER, PERIOD_S, models, p),
                   PERIOD_S, parameters, reference, flavour=flavour)


def state(altitude_m: float = 0.0, climb_mps: float = 0.0, north_m: float = 0.0,
          yaw_rad: float = 0.0) -> np.ndarray:
    """A measurement: position NED, velocity NED, Euler angles, Euler rates."""
    m = np.zeros(12)
    m[0], m[2], m[5], m[8] = north_m, -altitude_m, -climb_mps, yaw_rad
    return m


GROUND = state()


def said(vehicle: Commander) -> list[tuple[int, str]]:
    """The STATUSTEXT queued since the last call (the shell sends and clears them)."""
    out = list(vehicle.messages)
    vehicle.messages.clear()
    return out


def on_the_ground(**kwargs) -> Commander:
    """Disarmed on the ground with the simulator link up; messages cleared."""
    v = make_vehicle(**kwargs)
    v.sample(0.0, GROUND)
    said(v)
    return v


def copter_flying(altitude_m: float = 2.5, **kwargs) -> Commander:
    """The ArduPilot-Copter flavour armed in GUIDED, in the air."""
    v = on_the_ground(flavour="ardupilot", **kwargs)
    v.set_mode(FlightMode.GUIDED, LINK0)
    v.arm(LINK0)
    v.sample(0.01, state(altitude_m))
    assert v.armed and not v.landed and v.mode == FlightMode.GUIDED
    said(v)
    return v


def flying(altitude_m: float = 2.5, **kwargs) -> Commander:
    """Armed in HOLD, in the air (state jumps there: the logic only reads the state)."""
    v = on_the_ground(**kwargs)
    v.arm(LINK0)
    v.sample(0.01, state(altitude_m))
    assert v.armed and not v.landed
    said(v)
    return v


def hold_setpoint(north: float = 0.0, east: float = 0.0, down: float = -2.5) -> Setpoint:
    return Setpoint(np.array([north, east, down]))


def offboard(vehicle: Commander, link_t_s: float, setpoint: Setpoint | None = None) -> None:
    """Stream one setpoint at ``link_t_s`` and switch to OFFBOARD."""
    vehicle.inputs.position_setpoint(link_t_s, setpoint or hold_setpoint())
    vehicle.set_mode(FlightMode.OFFBOARD, link_t_s)
    assert vehicle.mode == FlightMode.OFFBOARD
    said(vehicle)


class Loop:
    """The vehicle flying the rigid-body plant in one process. Sim time is whole
    microseconds, as the simulator stamps samples; the link clock runs LINK0 ahead."""

    def __init__(self, controller: str = "pid", models=None, **parameters) -> None:
        self.plant = Plant(PAPER, "rigid-body", 0.001, ground_contact=True)
        self.vehicle = make_vehicle(controller, models=models, **parameters)
        self.k = 0
        self.log: list[tuple[float, np.ndarray, bool, bool, FlightMode]] = []
        self.said: list[tuple[float, int, str]] = []  # (sim time, severity, text)

    @property
    def t_s(self) -> float:
        return self.k * PERIOD_US / 1e6

    @property
    def link_s(self) -> float:
        return LINK0 + self.t_s

    def step(self) -> None:
        v = self.vehicle
        v.check_links(self.link_s)
        measurement = self.plant.true_measurement()
        commands = v.step(self.t_s, measurement)
        self.said += [(self.t_s, s, text) for s, text in said(v)]
        self.log.append((self.t_s, measurement, v.landed, v.armed, v.mode))
        self.plant.set_motor_commands(commands)
        self.plant.advance(PERIOD_S)
        self.k += 1

    def run(self, duration_s: float) -> None:
        for _ in range(round(duration_s / PERIOD_S)):
            self.step()

    def run_until(self, done, limit_s: float) -> float:
        """Step until ``done()``; the sim time of the step that made it true."""
        end = self.k + round(limit_s / PERIOD_S)
        while self.k < end:
            self.step()
            if done():
                return self.log[-1][0]
        raise AssertionError(f"not done within {limit_s} s of sim time")

    def texts(self) -> list[str]:
        return [text for _t, _s, text in self.said]

    def when(self, text: str) -> float:
        return next(t for t, _s, said_text in self.said if said_text == text)

    def rows(self, since_s: float = -math.inf, until_s: float = math.inf) -> np.ndarray:
        return np.array([m for t, m, *_ in self.log if since_s <= t <= until_s])


# -- the parameters the timings below come from -------------------------------------------
def test_the_vehicle_parameters_have_their_documented_defaults():
    assert {name: DEFAULTS[name] for name in (
        "MIS_TAKEOFF_ALT", "MPC_TKO_SPEED", "MPC_LAND_SPEED", "COM_DISARM_LAND",
        "COM_DL_LOSS_T", "NAV_DLL_ACT", "COM_OF_LOSS_T", "COM_OBL_ACT", "COM_SIM_LOSS_T")} == {
        "MIS_TAKEOFF_ALT": 2.5, "MPC_TKO_SPEED": 1.0, "MPC_LAND_SPEED": 0.7,
        "COM_DISARM_LAND": 1.0, "COM_DL_LOSS_T": 10.0, "NAV_DLL_ACT": 1.0,
        "COM_OF_LOSS_T": 1.0, "COM_OBL_ACT": 1.0, "COM_SIM_LOSS_T": 0.5}


def test_a_new_vehicle_is_disarmed_landed_in_its_flavours_start_mode_and_silent():
    v = make_vehicle()
    assert (v.armed, v.landed, v.mode, v.failsafe, v.sim_link_ok) == (
        False, True, FlightMode.HOLD, None, False)
    assert v.messages == []
    assert make_vehicle(flavour="ardupilot").mode == FlightMode.STABILIZED  # STABILIZE
    assert np.array_equal(v.control(), np.zeros(4))  # no state: motors off


@pytest.mark.parametrize("name, value", [
    ("COM_DL_LOSS_T", 0.5), ("COM_DL_LOSS_T", math.nan), ("NAV_DLL_ACT", 2.5),
    ("COM_OBL_ACT", 0.5), ("NO_SUCH_PARAM", 1.0), ("MIS_TAKEOFF_ALT", math.inf)])
def test_a_refused_parameter_keeps_the_value_in_force(name, value):
    v = on_the_ground()
    before = dict(v.parameters)
    with pytest.raises(RefusedError, match="parameter") as refused:
        v.set_parameter(name, value)
    assert not refused.value.temporary
    assert v.parameters == before


# -- arming ----------------------------------------------------------------------------
def test_arming_needs_state_from_the_simulator_temporarily():
    v = make_vehicle()
    with pytest.raises(RefusedError, match="^arming denied: no state from the simulator$") \
            as refused:
        v.arm(LINK0)
    assert refused.value.temporary and not v.armed
    v.sample(0.0, GROUND)
    v.sim_link_lost()  # the state is known but the link is down
    with pytest.raises(RefusedError, match="no state from the simulator") as refused:
        v.arm(LINK0)
    assert refused.value.temporary and not v.armed
    v.sample(0.01, GROUND)  # link up again
    v.arm(LINK0)
    assert v.armed


def test_arming_waits_for_the_estimator_and_says_why():
    """On the estimator, the pre-arm check is its convergence: refused (temporarily) with
    its reason, then accepted once it has converged; SYS_STATUS says the same."""
    from autopilot.mavlink.telemetry import PREARM, sys_status

    v = make_vehicle()
    v.sample(0.0, GROUND)
    v.navigation_problem = "estimator settling after alignment"
    with pytest.raises(RefusedError, match="^arming denied: estimator settling after "
                                           "alignment$") as refused:
        v.arm(LINK0)
    assert refused.value.temporary and not v.armed
    assert not sys_status(v, 0.0, 0).onboard_control_sensors_health & PREARM
    v.navigation_problem = None
    assert sys_status(v, 0.0, 0).onboard_control_sensors_health & PREARM
    v.arm(LINK0)
    assert v.armed


@pytest.mark.parametrize("mode", [FlightMode.LAND, FlightMode.REFERENCE])
def test_arming_is_denied_in_a_mode_that_cannot_be_armed(mode):
    # No command leaves a disarmed vehicle in these modes (disarming leaves them), so the
    # mode is set directly to reach the check.
    v = on_the_ground()
    v.mode = mode
    with pytest.raises(RefusedError, match=f"^arming denied in {mode.value} mode$") as refused:
        v.arm(LINK0)
    assert not refused.value.temporary and not v.armed and said(v) == []


def test_arming_is_denied_in_the_air():
    v = on_the_ground()
    v.sample(0.01, state(altitude_m=1.0))
    assert not v.landed
    with pytest.raises(RefusedError, match="^arming denied: not on the ground$") as refused:
        v.arm(LINK0)
    assert not refused.value.temporary and not v.armed


def test_arming_in_offboard_needs_the_setpoint_stream_within_com_of_loss_t():
    v = on_the_ground(COM_OF_LOSS_T=2.0)
    offboard(v, LINK0)  # disarmed in OFFBOARD: the mode is allowed, the stream decides
    with pytest.raises(RefusedError, match="^arming denied: no offboard setpoints$") \
            as refused:
        v.arm(LINK0 + 2.0 + EPS)
    assert refused.value.temporary and not v.armed
    v.arm(LINK0 + 2.0 - EPS)
    assert v.armed and v.mode == FlightMode.OFFBOARD
    assert said(v) == [(INFO, "armed")]


@pytest.mark.parametrize("flavour, mode", [("px4", FlightMode.HOLD),
                                           ("px4", FlightMode.GUIDED),
                                           ("ardupilot", FlightMode.GUIDED),
                                           ("ardupilot", FlightMode.HOLD)])
def test_arming_on_the_ground_holds_where_the_vehicle_is(flavour, mode):
    v = on_the_ground(flavour=flavour)
    v.sample(0.02, state(north_m=3.0, yaw_rad=0.5))
    if v.mode != mode:
        v.set_mode(mode, LINK0)
    said(v)
    v.arm(LINK0)
    assert v.armed and v.landed and v.mode == mode
    assert said(v) == [(INFO, "armed" if flavour == "px4" else "Arming motors")]
    assert np.array_equal(v.setpoint.position_ned_m, [3.0, 0.0, 0.0])
    assert v.setpoint.yaw_rad == pytest.approx(0.5)
    v.arm(LINK0)  # again: nothing happens, nothing is said
    assert v.armed and said(v) == []


def test_disarming_is_denied_in_the_air_unless_forced():
    v = flying()
    with pytest.raises(RefusedError, match=r"^disarming denied: in the air \(force with "
                                           r"param2 21196\)$") as refused:
        v.disarm()
    assert not refused.value.temporary and v.armed
    v.disarm(force=True)
    assert not v.armed and said(v) == [(INFO, "disarmed")]
    assert np.array_equal(v.control(), np.zeros(4))
    v.disarm()  # disarmed already: nothing
    assert said(v) == []


def test_disarming_on_the_ground_is_accepted_and_motors_stop():
    v = on_the_ground()
    v.arm(LINK0)
    v.step(0.01, GROUND)
    said(v)
    v.disarm()
    assert not v.armed and said(v) == [(INFO, "disarmed")]
    assert np.array_equal(v.step(0.02, GROUND), np.zeros(4))


# -- the ground-station link failsafe ---------------------------------------------------
@pytest.mark.parametrize("action, mode, text", [
    (0, FlightMode.OFFBOARD, "ground station lost"),
    (1, FlightMode.HOLD, "ground station lost: hold"),
    (3, FlightMode.LAND, "ground station lost: land")])
@pytest.mark.parametrize("timeout_s", [DEFAULTS["COM_DL_LOSS_T"], 3.0])
def test_ground_station_loss_in_the_air_fires_after_com_dl_loss_t_with_nav_dll_act(
        timeout_s, action, mode, text):
    v = flying(COM_DL_LOSS_T=timeout_s, NAV_DLL_ACT=action)
    offboard(v, LINK0)  # not HOLD already, so that hold shows too
    v.inputs.gcs_heartbeat(LINK0)
    v.inputs.position_setpoint(LINK0 + timeout_s, hold_setpoint())  # the offboard stream goes on
    v.check_links(LINK0 + timeout_s - EPS)
    assert v.mode == FlightMode.OFFBOARD and not v.gcs_lost and v.failsafe is None
    assert said(v) == []
    v.check_links(LINK0 + timeout_s + EPS)
    assert v.gcs_lost and v.failsafe == "ground station lost" and v.armed
    assert v.mode == mode
    expected = [(WARNING, text)]
    if mode != FlightMode.OFFBOARD:
        expected.append((INFO, f"mode {mode.value}"))
    assert said(v) == expected
    v.check_links(LINK0 + timeout_s + 0.5)  # fires once
    assert said(v) == []
    v.inputs.gcs_heartbeat(LINK0 + timeout_s + 1.0)
    assert not v.gcs_lost and v.mode == mode  # the failsafe's mode stays
    assert said(v) == [(NOTICE, "ground station link regained")]


def test_each_heartbeat_restarts_the_ground_station_timeout():
    v = flying(COM_DL_LOSS_T=3.0)
    for k in range(5):
        v.inputs.gcs_heartbeat(LINK0 + 2.0 * k)
        v.check_links(LINK0 + 2.0 * k + 3.0 - EPS)
    assert not v.gcs_lost
    v.check_links(LINK0 + 8.0 + 3.0 + EPS)
    assert v.gcs_lost and v.mode == FlightMode.HOLD


def test_no_ground_station_loss_before_one_was_heard():
    v = flying()
    v.check_links(LINK0 + 1e6)
    assert not v.gcs_lost and v.failsafe is None and said(v) == []


@pytest.mark.parametrize("action", [1, 3])
def test_ground_station_loss_on_the_ground_disarms(action):
    v = on_the_ground(NAV_DLL_ACT=action)
    v.arm(LINK0)
    said(v)
    v.inputs.gcs_heartbeat(LINK0)
    v.check_links(LINK0 + 10.0 + EPS)
    assert not v.armed and v.mode == FlightMode.HOLD
    assert said(v) == [(INFO, "ground station lost: disarmed on the ground")]


def test_ground_station_loss_with_no_action_leaves_an_armed_vehicle_on_the_ground_armed():
    v = on_the_ground(NAV_DLL_ACT=0)
    v.arm(LINK0)
    said(v)
    v.inputs.gcs_heartbeat(LINK0)
    v.check_links(LINK0 + 10.0 + EPS)
    assert v.armed and said(v) == [(WARNING, "ground station lost")]


def test_ground_station_loss_while_disarmed_is_only_said():
    v = on_the_ground(NAV_DLL_ACT=3)
    v.inputs.gcs_heartbeat(LINK0)
    v.check_links(LINK0 + 10.0 + EPS)
    assert v.gcs_lost and not v.armed and v.mode == FlightMode.HOLD
    assert said(v) == [(WARNING, "ground station lost")]


# -- the offboard setpoint failsafe ------------------------------------------------------
@pytest.mark.parametrize("action, mode", [(0, FlightMode.LAND), (1, FlightMode.HOLD)])
@pytest.mark.parametrize("timeout_s", [DEFAULTS["COM_OF_LOSS_T"], 0.5, 5.0])
def test_setpoint_loss_in_offboard_fires_after_com_of_loss_t_with_com_obl_act(
        timeout_s, action, mode):
    v = flying(COM_OF_LOSS_T=timeout_s, COM_OBL_ACT=action)
    offboard(v, LINK0)
    v.inputs.position_setpoint(LINK0 + 0.25, hold_setpoint())  # the stream's last setpoint
    v.check_links(LINK0 + 0.25 + timeout_s - EPS)
    assert v.mode == FlightMode.OFFBOARD and v.failsafe is None and said(v) == []
    v.check_links(LINK0 + 0.25 + timeout_s + EPS)
    assert v.mode == mode and v.armed and v.failsafe == "offboard setpoints lost"
    assert said(v) == [(WARNING, f"offboard setpoints lost: {mode.value}"),
                       (INFO, f"mode {mode.value}")]
    v.check_links(LINK0 + 100.0)
    assert said(v) == []


def test_refused_setpoints_do_not_keep_the_stream_alive():
    v = flying()
    offboard(v, LINK0)
    for k in range(1, 20):  # a 20 Hz stream of bad setpoints
        with pytest.raises(RefusedError):
            v.inputs.position_setpoint(LINK0 + 0.05 * k, hold_setpoint(down=math.inf))
    v.check_links(LINK0 + 1.0 - EPS)
    assert v.mode == FlightMode.OFFBOARD
    v.check_links(LINK0 + 1.0 + EPS)
    assert v.mode == FlightMode.HOLD


def test_attitude_setpoints_count_as_the_stream():
    v = flying()
    offboard(v, LINK0)
    v.inputs.attitude_setpoint(LINK0 + 0.5, (1.0, 0.0, 0.0, 0.0), None)
    v.check_links(LINK0 + 1.5 - EPS)
    assert v.mode == FlightMode.OFFBOARD and v.state.attitude_target is not None
    v.check_links(LINK0 + 1.5 + EPS)
    assert v.mode == FlightMode.HOLD and v.state.attitude_target is None


def test_setpoint_loss_on_the_ground_disarms_then_leaves_offboard():
    v = on_the_ground()
    offboard(v, LINK0)
    v.arm(LINK0)
    said(v)
    v.check_links(LINK0 + 1.0 + EPS)
    assert not v.armed
    assert said(v) == [(INFO, "offboard setpoints lost: disarmed on the ground")]
    v.check_links(LINK0 + 1.0 + 2 * EPS)  # disarmed without a stream: back to HOLD, quietly
    assert v.mode == FlightMode.HOLD and said(v) == []


def test_a_disarmed_vehicle_leaves_offboard_quietly_when_the_stream_stops():
    v = on_the_ground()
    offboard(v, LINK0)
    v.check_links(LINK0 + 1.0 - EPS)
    assert v.mode == FlightMode.OFFBOARD
    v.check_links(LINK0 + 1.0 + EPS)
    assert v.mode == FlightMode.HOLD and v.failsafe is None and said(v) == []


# -- the simulator link ----------------------------------------------------------------
def test_simulator_link_loss_in_the_air_lands_and_landing_resumes_with_state():
    v = flying()
    v.sim_link_lost()
    assert v.mode == FlightMode.LAND and v.armed and not v.sim_link_ok
    assert v.failsafe == "simulator link lost"
    assert said(v) == [(WARNING, "simulator link lost: land"), (INFO, "mode land")]
    assert np.array_equal(v.control(), np.zeros(4))  # no state: no commands
    v.sim_link_lost()  # lost already: said once
    assert said(v) == []
    commands = v.step(0.02, state(2.5))
    assert said(v) == [(INFO, "simulator link up")]
    assert v.mode == FlightMode.LAND and np.all(commands > 0.0)


def test_simulator_link_loss_on_the_ground_disarms_and_disarmed_is_only_said():
    v = on_the_ground()
    v.arm(LINK0)
    said(v)
    v.sim_link_lost()
    assert not v.armed and said(v) == [(INFO, "simulator link lost: disarmed on the ground")]
    v.sample(0.02, GROUND)
    said(v)
    v.sim_link_lost()
    assert said(v) == [(WARNING, "simulator link lost")]


def test_a_restarted_simulator_disarms_a_vehicle_on_the_ground():
    v = flying()
    v.sample(5.0, state(2.5))
    v.sample(0.0, GROUND)  # the clock went back: a new simulator, on the ground
    assert not v.armed
    assert said(v) == [(NOTICE, "simulator restarted"),
                       (INFO, "simulator restarted: disarmed on the ground")]


def _watchdog(vehicle: Commander, lockstep: bool):
    """The autopilot process's simulator-link watchdog, without sockets: the simulator
    socket is a stand-in and the wall time of the last sample is set by hand."""
    from autopilot.mavlink.server import MavlinkServer
    from autopilot.process.loop import Autopilot, AutopilotConfig

    autopilot = Autopilot(AutopilotConfig(lockstep=lockstep), vehicle,
                          MavlinkServer(vehicle, []),  # the watchdog uses no ground link
                          log=lambda text: None)
    autopilot.sim.sock = object()
    autopilot._last_sample_wall = LINK0
    return autopilot


@pytest.mark.parametrize("timeout_s", [DEFAULTS["COM_SIM_LOSS_T"], 2.0])
def test_no_sample_for_com_sim_loss_t_in_real_time_loses_the_simulator_link(timeout_s):
    v = flying(COM_SIM_LOSS_T=timeout_s)
    autopilot = _watchdog(v, lockstep=False)
    autopilot._sim_watchdog(LINK0 + timeout_s - EPS)
    assert v.sim_link_ok and v.mode == FlightMode.HOLD
    autopilot._sim_watchdog(LINK0 + timeout_s + EPS)
    assert not v.sim_link_ok and v.mode == FlightMode.LAND
    assert said(v) == [(WARNING, "simulator link lost: land"), (INFO, "mode land")]
    lockstep = _watchdog(flying(), lockstep=True)  # lockstep: time stops with the simulator
    lockstep._sim_watchdog(LINK0 + 1e6)
    assert lockstep.vehicle.sim_link_ok


# -- modes -----------------------------------------------------------------------------
def test_setting_the_mode_in_force_does_nothing():
    v = flying()
    v.set_mode(FlightMode.HOLD, LINK0)
    assert said(v) == []


@pytest.mark.parametrize("armed, mode, reason, temporary", [
    (False, FlightMode.OFFBOARD, "^offboard denied: no setpoint stream$", True),
    (True, FlightMode.OFFBOARD, "^offboard denied: no setpoint stream$", True),
    (False, FlightMode.TAKEOFF, "^take-off denied: disarmed$", True),
    (False, FlightMode.LAND, "^landing denied: disarmed$", True),
    (False, FlightMode.REFERENCE, "^no reference generator configured$", False),
])
def test_mode_changes_refused_and_why(armed, mode, reason, temporary):
    v = on_the_ground()
    if armed:
        v.arm(LINK0)
        said(v)
    with pytest.raises(RefusedError, match=reason) as refused:
        v.set_mode(mode, LINK0)
    assert refused.value.temporary == temporary
    assert v.mode == FlightMode.HOLD and v.armed == armed and said(v) == []


def test_land_command_needs_an_armed_vehicle():
    v = on_the_ground()
    with pytest.raises(RefusedError, match="^landing denied: disarmed$") as refused:
        v.land()
    assert refused.value.temporary and v.mode == FlightMode.HOLD


def test_offboard_needs_a_setpoint_within_com_of_loss_t_and_flies_the_newest():
    v = flying(COM_OF_LOSS_T=0.5)
    v.inputs.position_setpoint(LINK0, hold_setpoint(1.0, 2.0, -3.0))
    v.inputs.position_setpoint(LINK0 + 0.1, hold_setpoint(4.0, 5.0, -6.0))
    assert np.array_equal(v.setpoint.position_ned_m, [0.0, 0.0, 0.0])  # HOLD: not taken
    with pytest.raises(RefusedError, match="no setpoint stream"):
        v.set_mode(FlightMode.OFFBOARD, LINK0 + 0.6 + EPS)
    v.set_mode(FlightMode.OFFBOARD, LINK0 + 0.6 - EPS)
    assert v.mode == FlightMode.OFFBOARD and said(v) == [(INFO, "mode offboard")]
    assert np.array_equal(v.setpoint.position_ned_m, [4.0, 5.0, -6.0])
    v.inputs.position_setpoint(LINK0 + 0.2, hold_setpoint(7.0, 8.0, -9.0))
    assert np.array_equal(v.setpoint.position_ned_m, [7.0, 8.0, -9.0])  # taken at once


def test_guided_takes_setpoints_without_a_stream_and_keeps_the_last():
    v = copter_flying()
    v.inputs.position_setpoint(LINK0, hold_setpoint(1.0, 2.0, -3.0))
    v.check_links(LINK0 + 100.0)
    assert v.mode == FlightMode.GUIDED
    assert np.array_equal(v.setpoint.position_ned_m, [1.0, 2.0, -3.0])


def test_hold_holds_where_the_vehicle_is():
    v = flying()
    offboard(v, LINK0, hold_setpoint(10.0, 0.0, -2.5))
    v.sample(0.02, state(altitude_m=3.0, north_m=1.0, yaw_rad=-0.25))
    v.set_mode(FlightMode.HOLD, LINK0)
    assert said(v) == [(INFO, "mode hold")]
    assert np.array_equal(v.setpoint.position_ned_m, [1.0, 0.0, -3.0])
    assert v.setpoint.yaw_rad == pytest.approx(-0.25)


def test_land_descends_to_below_the_ground_from_where_the_vehicle_is():
    v = flying()
    v.sample(0.02, state(altitude_m=3.0, north_m=1.0))
    v.land()
    assert v.mode == FlightMode.LAND and said(v) == [(INFO, "mode land")]
    assert np.array_equal(v.setpoint.position_ned_m, [1.0, 0.0, 0.5])


def test_the_reference_needs_an_armed_vehicle_in_the_air_and_starts_at_the_mode_change():
    v = on_the_ground(reference=Reference("hover", altitude_m=1.0))
    for arm in (False, True):
        if arm:
            v.arm(LINK0)
        with pytest.raises(RefusedError, match="^the reference needs an armed vehicle in "
                                               "the air$") as refused:
            v.set_mode(FlightMode.REFERENCE, LINK0)
        assert refused.value.temporary and v.mode == FlightMode.HOLD
    v.sample(3.25, state(altitude_m=1.0))
    said(v)
    v.set_mode(FlightMode.REFERENCE, LINK0)
    assert v.mode == FlightMode.REFERENCE and v.reference_start_s == 3.25
    assert said(v) == [(INFO, "mode reference")]


def test_arm_in_reference_flies_the_reference_at_once_and_needs_one():
    with pytest.raises(RefusedError, match="no reference generator"):
        on_the_ground().arm_in_reference()
    v = make_vehicle(reference=Reference("hover", altitude_m=1.0))
    v.sample(0.5, state(altitude_m=1.0))
    v.arm_in_reference()
    assert v.armed and v.mode == FlightMode.REFERENCE and v.reference_start_s == 0.5
    assert not v.landed


@pytest.mark.parametrize("altitude", [0.49, 100.01, -2.0, math.nan, math.inf])
def test_take_off_altitude_must_be_within_half_a_metre_and_100_m(altitude):
    v = on_the_ground()
    v.arm(LINK0)
    said(v)
    with pytest.raises(RefusedError, match="is outside \\[0.5, 100\\] m") as refused:
        v.takeoff(altitude)
    assert not refused.value.temporary
    assert v.mode == FlightMode.HOLD and v.takeoff_altitude_m is None and said(v) == []


@pytest.mark.parametrize("altitude, expected", [(None, 2.5), (0.5, 0.5), (100.0, 100.0)])
def test_take_off_goes_to_the_given_altitude_or_mis_takeoff_alt(altitude, expected):
    v = on_the_ground()
    v.arm(LINK0)
    said(v)
    v.takeoff(altitude)
    assert v.mode == FlightMode.TAKEOFF and v.takeoff_altitude_m == expected
    assert v.setpoint.position_ned_m[2] == -expected
    assert said(v) == [(INFO, f"taking off to {expected:.1f} m")]


def test_take_off_by_mode_uses_mis_takeoff_alt():
    v = on_the_ground(MIS_TAKEOFF_ALT=4.0)
    v.arm(LINK0)
    v.set_mode(FlightMode.TAKEOFF, LINK0)
    assert v.mode == FlightMode.TAKEOFF and v.takeoff_altitude_m == 4.0


def test_ardupilot_takes_off_in_guided_only_and_stays_guided():
    v = on_the_ground(flavour="ardupilot")
    v.set_mode(FlightMode.HOLD, LINK0)  # LOITER: armable in Copter
    v.arm(LINK0)
    with pytest.raises(RefusedError, match="^take-off needs GUIDED mode$") as refused:
        v.takeoff(2.0)
    assert not refused.value.temporary
    v.set_mode(FlightMode.GUIDED, LINK0)
    v.takeoff(2.0)
    assert v.mode == FlightMode.GUIDED and v.takeoff_altitude_m == 2.0


def test_take_off_disarmed_is_refused_temporarily():
    v = on_the_ground()
    with pytest.raises(RefusedError, match="^take-off denied: disarmed$") as refused:
        v.takeoff(None)
    assert refused.value.temporary and v.takeoff_altitude_m is None


# -- land detection --------------------------------------------------------------------
def test_landed_on_the_ground_cleared_in_the_air_and_announced_when_armed():
    v = on_the_ground()
    assert v.landed
    v.arm(LINK0)
    v.sample(0.01, GROUND)
    assert v.landed  # armed on the ground in HOLD: still landed
    v.sample(0.02, state(altitude_m=LANDED_ALTITUDE_M + 0.01))
    assert not v.landed
    v.sample(0.03, state(altitude_m=0.0, climb_mps=-(LANDED_SPEED_MPS + 0.05)))
    assert not v.landed  # at ground height but still moving
    said(v)
    v.sample(0.04, state(altitude_m=LANDED_ALTITUDE_M - 0.01, climb_mps=-0.05))
    assert v.landed and said(v) == [(INFO, "landed")]
    v.disarm()
    v.sample(0.05, state(altitude_m=1.0))
    v.sample(0.06, GROUND)
    assert v.landed and said(v) == [(INFO, "disarmed")]  # disarmed: not announced


def test_a_vehicle_taking_off_is_not_landed_even_on_the_ground():
    v = on_the_ground()
    v.arm(LINK0)
    v.takeoff(2.0)
    v.sample(0.01, GROUND)
    assert not v.landed


@pytest.mark.parametrize("delay_s", [DEFAULTS["COM_DISARM_LAND"], 0.0, 2.5])
def test_land_disarms_com_disarm_land_after_touchdown(delay_s):
    v = flying(COM_DISARM_LAND=delay_s)
    v.land()
    v.sample(9.0, state(altitude_m=0.5, climb_mps=-0.7))
    said(v)
    v.sample(10.0, GROUND)  # touchdown
    assert v.landed
    if delay_s == 0.0:
        assert not v.armed and said(v) == [(INFO, "landed"), (INFO, "landed: disarmed")]
        return
    assert v.armed and said(v) == [(INFO, "landed")]
    v.sample(10.0 + delay_s - EPS, GROUND)
    assert v.armed
    v.sample(10.0 + delay_s, GROUND)
    assert not v.armed and v.mode == FlightMode.HOLD
    assert said(v) == [(INFO, "landed: disarmed")]


def test_a_bounce_restarts_the_landing_disarm_delay():
    v = flying(COM_DISARM_LAND=2.0)
    v.land()
    v.sample(10.0, GROUND)
    v.sample(11.0, state(altitude_m=0.2))  # bounced
    v.sample(11.5, GROUND)
    v.sample(13.5 - EPS, GROUND)
    assert v.armed
    v.sample(13.5, GROUND)
    assert not v.armed


# -- setpoint validation ---------------------------------------------------------------
BAD_SETPOINTS = [
    (Setpoint(np.array([math.nan, 0.0, -2.0])), "x without y"),
    (Setpoint(np.array([math.inf, 0.0, -2.0])), "setpoint position holds an infinity"),
    (Setpoint(np.array([0.0, -math.inf, -2.0])), "setpoint position holds an infinity"),
    (Setpoint(np.array([0.0, 0.0, 1000.5])), "setpoint position 1000.5 is beyond"),
    (Setpoint(np.array([1e4, 0.0, -2.0])), "setpoint position 10000 is beyond"),
    (Setpoint(), "neither position nor velocity"),
    (Setpoint(np.array([0.0, 0.0, math.nan]), np.array([math.nan, math.nan, math.nan])),
     "neither position nor velocity"),
    (Setpoint(velocity_ned_mps=np.array([20.5, 0.0, 0.0])), "velocity 20.5 is beyond"),
    (Setpoint(velocity_ned_mps=np.array([0.0, 0.0, -math.inf])), "velocity holds an inf"),
    (Setpoint(np.array([0.0, 0.0, -2.0]), accel_ned_mps2=np.array([0.0, 21.0, 0.0])),
     "acceleration 21 is beyond"),
    (Setpoint(np.array([0.0, 0.0, -2.0]), yaw_rad=math.inf), "yaw holds an infinity"),
    (Setpoint(np.array([0.0, 0.0, -2.0]), yaw_rate_rad_s=-20.5), "yaw rate -20.5 is beyond"),
]


def _snapshot(setpoint: Setpoint) -> np.ndarray:
    return np.concatenate((setpoint.position_ned_m, setpoint.velocity_ned_mps,
                           setpoint.accel_ned_mps2, [setpoint.yaw_rad, setpoint.yaw_rate_rad_s]))


@pytest.mark.parametrize("bad, reason", BAD_SETPOINTS)
def test_bad_position_setpoints_are_refused_and_change_nothing(bad, reason):
    v = flying()
    good = hold_setpoint(1.0, 2.0, -3.0)
    offboard(v, LINK0, good)
    before = _snapshot(v.setpoint)
    with pytest.raises(RefusedError, match=reason) as refused:
        v.inputs.position_setpoint(LINK0 + 0.5, bad)
    assert not refused.value.temporary
    np.testing.assert_array_equal(_snapshot(v.setpoint), before)  # NaN equals NaN here
    # the stream was not refreshed
    assert not v.inputs.streaming(Stream.SETPOINTS, LINK0 + 1.0 + EPS)
    assert said(v) == []


def test_setpoints_at_the_limits_are_taken_and_the_yaw_wrapped():
    v = flying()
    offboard(v, LINK0)
    v.inputs.position_setpoint(LINK0, Setpoint(np.array([1000.0, -1000.0, -1000.0]),
                                        np.array([20.0, -20.0, 20.0]),
                                        np.array([20.0, 20.0, -20.0]), 3 * math.pi, math.nan))
    assert np.array_equal(v.setpoint.position_ned_m, [1000.0, -1000.0, -1000.0])
    assert abs(v.setpoint.yaw_rad) == pytest.approx(math.pi)
    v.inputs.position_setpoint(LINK0, Setpoint(velocity_ned_mps=np.array([1.0, 2.0, 0.5]),
                                        yaw_rate_rad_s=20.0))
    assert np.array_equal(v.setpoint.velocity_ned_mps, [1.0, 2.0, 0.5])


def test_a_still_position_setpoint_drops_its_feed_forward_after_half_a_second():
    v = flying()
    moving = Setpoint(np.array([1.0, 0.0, -2.5]), np.array([1.0, 0.0, 0.0]))
    offboard(v, LINK0, moving)
    for t, x in ((0.1, 1.1), (0.2, 1.2)):  # the setpoint moves: feed-forward applies
        v.inputs.position_setpoint(LINK0 + t, Setpoint(np.array([x, 0.0, -2.5]),
                                                np.array([1.0, 0.0, 0.0])))
        assert v.setpoint.velocity_ned_mps[0] == 1.0
    still = Setpoint(np.array([1.2, 0.0, -2.5]), np.array([1.0, 0.0, 0.0]))
    v.inputs.position_setpoint(LINK0 + 0.7 - EPS, still)
    assert v.setpoint.velocity_ned_mps[0] == 1.0
    v.inputs.position_setpoint(LINK0 + 0.7 + EPS, still)
    assert math.isnan(v.setpoint.velocity_ned_mps[0])


@pytest.mark.parametrize("quaternion, thrust, reason", [
    (None, 0.5, "without attitude"),
    ((math.nan, 0.0, 0.0, 0.0), 0.5, "attitude quaternion holds NaN"),
    ((0.5, 0.0, 0.0, 0.0), 0.5, "norm 0.500 is not 1"),
    (tuple(quat_from_euler(1.05, 0.0, 0.0)), 0.5, "tilts more than 1.0 rad"),
    (tuple(quat_from_euler(0.0, -1.05, 0.0)), 0.5, "tilts more than 1.0 rad"),
    ((1.0, 0.0, 0.0, 0.0), 1.5, "thrust 1.5 is beyond"),
    ((1.0, 0.0, 0.0, 0.0), -0.1, "thrust -0.1 is outside"),
    ((1.0, 0.0, 0.0, 0.0), math.nan, "thrust holds NaN"),
])
def test_bad_attitude_setpoints_are_refused_and_change_nothing(quaternion, thrust, reason):
    v = flying()
    offboard(v, LINK0)
    v.inputs.attitude_setpoint(LINK0, (1.0, 0.0, 0.0, 0.0), 0.3)
    target = v.state.attitude_target
    with pytest.raises(RefusedError, match=reason):
        v.inputs.attitude_setpoint(LINK0 + 0.5, quaternion, thrust)
    assert v.state.attitude_target is target and target.thrust_fraction == 0.3
    assert not v.inputs.streaming(Stream.SETPOINTS, LINK0 + 1.0 + EPS)


def test_attitude_thrust_is_read_as_the_flavour_reads_it():
    px4 = flying()
    offboard(px4, LINK0)
    px4.inputs.attitude_setpoint(LINK0, tuple(quat_from_euler(0.2, 0.0, 0.0)), 0.25)
    assert px4.state.attitude_target.thrust_fraction == 0.25
    assert px4.state.attitude_target.euler_rad[0] == pytest.approx(0.2)
    copter = copter_flying(MPC_TKO_SPEED=2.0)
    copter.inputs.attitude_setpoint(LINK0, (1.0, 0.0, 0.0, 0.0), 1.0)
    assert copter.state.attitude_target.climb_rate_mps == 2.0  # (1 - 0.5) * 2 * MPC_TKO_SPEED
    assert math.isnan(copter.state.attitude_target.thrust_fraction)


# -- flights: the real controller and the plant, in sim time ------------------------------
@pytest.mark.parametrize("controller", ["pid", "smc", "ivfc"])
def test_take_off_climbs_at_mpc_tko_speed_to_mis_takeoff_alt_then_holds(controller,
                                                                         shipped_models):
    alt, speed = 1.5, 0.8
    loop = Loop(controller, shipped_models, MIS_TAKEOFF_ALT=alt, MPC_TKO_SPEED=speed)
    loop.run(0.05)
    assert loop.texts() == ["simulator link up"]
    assert loop.vehicle.landed
    loop.vehicle.arm(loop.link_s)
    loop.vehicle.set_mode(FlightMode.TAKEOFF, loop.link_s)
    loop.step()
    assert not loop.vehicle.landed and loop.vehicle.mode == FlightMode.TAKEOFF
    done = loop.run_until(lambda: loop.vehicle.takeoff_altitude_m is None, 10.0)
    assert loop.texts() == ["simulator link up", "armed", f"taking off to {alt:.1f} m",
                            "take-off complete", "mode hold"]
    assert loop.vehicle.mode == FlightMode.HOLD and loop.vehicle.armed
    climb = loop.rows()
    assert abs(climb[-1][2] + alt) < TAKEOFF_REACHED_M  # complete within 0.1 m
    assert max(-climb[:, 5]) == pytest.approx(speed, abs=0.01)  # climbs at MPC_TKO_SPEED
    assert done >= alt / speed  # no faster than that
    loop.run(3.0)
    held = loop.rows(since_s=done + 2.0)
    assert np.ptp(held[:, 2]) < 0.01 and abs(held[-1][2] + alt) < TAKEOFF_REACHED_M
    assert np.max(np.abs(held[:, 0:2])) < 0.01  # straight up


def test_take_off_ends_holding_at_the_take_off_altitude():
    loop = Loop("smc")
    loop.run(0.05)
    loop.vehicle.arm(loop.link_s)
    loop.vehicle.takeoff(None)
    loop.run_until(lambda: loop.vehicle.takeoff_altitude_m is None, 10.0)
    loop.run(5.0)
    assert -loop.plant.true_measurement()[2] == pytest.approx(DEFAULTS["MIS_TAKEOFF_ALT"], abs=0.02)


@pytest.mark.parametrize("controller", ["pid", "smc", "ivfc"])
def test_land_descends_at_mpc_land_speed_and_disarms_com_disarm_land_after_touchdown(
        controller, shipped_models):
    speed, delay = 0.5, 2.0
    loop = Loop(controller, shipped_models, MPC_LAND_SPEED=speed, COM_DISARM_LAND=delay)
    loop.run(0.05)
    loop.vehicle.arm(loop.link_s)
    loop.vehicle.takeoff(1.5)
    loop.run_until(lambda: loop.vehicle.mode == FlightMode.HOLD, 10.0)
    loop.run(1.0)
    said_before = len(loop.said)
    loop.vehicle.land()
    start = loop.t_s
    landed = loop.run_until(lambda: loop.vehicle.landed, 10.0)
    disarmed = loop.run_until(lambda: not loop.vehicle.armed, delay + 1.0)
    assert loop.texts()[said_before:] == ["mode land", "landed", "landed: disarmed"]
    assert loop.when("landed") == landed
    # Sim time is whole periods: disarmed at the first sample COM_DISARM_LAND after.
    assert delay <= disarmed - landed < delay + PERIOD_S + 1e-9
    descent = loop.rows(since_s=start, until_s=landed)
    assert max(descent[:, 5]) == pytest.approx(speed, abs=0.01)  # descends at its speed
    assert landed - start >= 1.4 / speed
    assert abs(loop.plant.true_measurement()[2]) < LANDED_ALTITUDE_M
    assert loop.vehicle.mode == FlightMode.HOLD
    loop.step()
    assert np.array_equal(loop.vehicle.last_commands, np.zeros(4))
    loop.vehicle.arm(loop.link_s)  # and it can fly again
    assert loop.vehicle.armed


def test_heartbeat_silence_in_flight_holds_after_com_dl_loss_t_on_the_link_clock():
    """Closed loop: the failsafe is timed on the link clock, whatever sim time does."""
    loop = Loop("smc", COM_DL_LOSS_T=2, NAV_DLL_ACT=3)  # whole seconds: INT32 as in PX4
    loop.run(0.05)
    loop.vehicle.inputs.gcs_heartbeat(loop.link_s)
    heard = loop.link_s
    loop.vehicle.arm(loop.link_s)
    loop.vehicle.takeoff(1.0)
    lost = loop.run_until(lambda: loop.vehicle.gcs_lost, 5.0)
    assert 2.0 < LINK0 + lost - heard <= 2.0 + PERIOD_S + 1e-9  # the first check after
    assert loop.vehicle.mode == FlightMode.LAND and "ground station lost: land" in loop.texts()
    loop.run_until(lambda: not loop.vehicle.armed, 10.0)
    assert loop.texts()[-2:] == ["landed", "landed: disarmed"]
