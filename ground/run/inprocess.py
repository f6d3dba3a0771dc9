"""Run a scenario with the plant and the autopilot's controller in one process.

The reference path for regression runs: no sockets, no clocks, sim time only, so the
same arguments give the same arrays bit for bit.
"""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from autopilot.control.cascade import SlidingModeCascade
from autopilot.control.factory import make_controller
from autopilot.estimation.estimator import Estimator, GpsFix
from autopilot.models.ts_model import FuzzyModelSet
from autopilot.parameters import validate_parameters
from contracts.airframe import Airframe, hover_rotor_speeds
from contracts.frames import DEFAULT_HOME, Home
from contracts.mavlink import fix_from_hil_gps, imu_from_hil_sensor, new_mavlink
from contracts.perturbations import (
    IN_PROCESS_KINDS,
    Perturbations,
    SensorEffects,
    sensor_effects_at,
)
from contracts.sim_samples import gps_message, sensor_message
from contracts.vectors import CHANNEL_INTERNALS, CHANNELS, MEASUREMENT_SIZE, REF_SIZE
from ground.record.run_files import RunRecord, left_the_envelope
from ground.scenario.scenario_file import Scenario
from sitl.plant import Plant
from sitl.sensors import SensorSuite, read_profile


def run_inprocess(
    scenario: Scenario,
    controller: str,
    plant_fidelity: str,
    airframe: Airframe,
    models: FuzzyModelSet | None = None,
    period_s: float = 0.01,
    plant_step_s: float = 0.001,
    parameters: dict[str, float] | None = None,
    sensors: str = "ideal",
    state_source: str = "auto",
    seed: int = 0,
    home: Home = DEFAULT_HOME,
    progress: Callable[[float], None] | None = None,
) -> RunRecord:
    """The scenario flown in one process. ``state_source`` "estimator" flies on the onboard
    estimator fed by the ``sensors`` profile's readings (one sample per control period,
    seeded as the simulator seeds them), as the processes do; otherwise on the plant's
    truth. ``progress`` hears the sim time [s] every tenth of a sim second. The first
    step loads (or compiles) the numerical core: its time is ``startup_wall_s``, not part
    of ``wall_time_s``."""
    if scenario.plan is not None:
        raise ValueError(f"{scenario.name} flies a mission: the vehicle's modes and navigator "
                         "run in the autopilot process (run it without --inprocess)")
    if scenario.ground_station is not None:
        raise ValueError(f"{scenario.name} has a [ground_station] on the vehicle's MAVLink "
                         "link: run it through the processes (without --inprocess)")
    unsupported = sorted({e.kind for e in scenario.perturbations
                          if e.kind not in IN_PROCESS_KINDS})
    if unsupported:
        raise ValueError(f"{', '.join(unsupported)} act on the simulator link; run "
                         f"{scenario.name} through the processes (without --inprocess)")
    n = int(round(scenario.duration_s / period_s))
    # Sim time in whole microseconds, as the simulator stamps its samples.
    period_us = round(period_s * 1e6)
    # Scenarios start in hover at the reference's altitude over the origin: the paper's
    # tests are about tracking, not take-off.
    # The ground is there, as in the simulator: a vehicle that flies into it stops.
    plant = Plant(airframe, plant_fidelity, plant_step_s,
                  position_ned_m=(0.0, 0.0, -scenario.reference.altitude_m),
                  rotor_rad_s=hover_rotor_speeds(airframe), ground_contact=True)
    ctrl = make_controller(controller, airframe, period_s, models, parameters)
    onboard = None
    if state_source == "estimator":
        suite = SensorSuite(read_profile(sensors), 1.0 / period_s, seed=seed, home=home)
        onboard = Estimator(gps_delay_s=validate_parameters(parameters or {})[
            "EKF2_GPS_DELAY"] / 1e3, home=home)
        previous_velocity = plant.state().velocity_ned_mps
        acceleration = np.zeros(3)
        truth_log = np.zeros((n, MEASUREMENT_SIZE))
    adaptive = isinstance(ctrl, SlidingModeCascade)
    meas_log = np.zeros((n, MEASUREMENT_SIZE))
    ref_log = np.zeros((n, REF_SIZE))
    kick_log = np.zeros((n, 2))
    cmd_log = np.zeros((n, 4))
    tel_log = np.full((n, len(CHANNELS), len(CHANNEL_INTERNALS)), np.nan)
    theta_g_log = np.full((n, len(CHANNELS)), np.nan)
    theta_f_log = (
        [np.zeros((n, len(t))) for t in ctrl.theta_f[:3]] if adaptive else []
    )
    active = Perturbations()
    diverged = False
    start = time.perf_counter()
    startup_wall_s = 0.0
    progress_every = max(1, round(0.1 / period_s))
    for k in range(n):
        if k == 1:  # the first step loaded the compiled code
            startup_wall_s = time.perf_counter() - start
            start = time.perf_counter()
        t = k * period_us / 1e6
        if progress is not None and k % progress_every == 0:
            progress(t)
        wanted = scenario.plant_perturbations_at(t)
        if wanted != active:
            plant.set_perturbations(wanted)
            active = wanted
        meas = plant.true_measurement()
        if onboard is not None:
            truth_log[k] = meas
            meas = _estimate(onboard, suite, home, k * period_us, plant, acceleration,
                             sensor_effects_at(scenario.perturbations, t))
        ref = scenario.reference.at(t)
        kick = np.array(scenario.kick_at(t))
        cmd = ctrl.step(meas, ref, scenario.reference.position_mode, kick)
        meas_log[k], ref_log[k], kick_log[k], cmd_log[k] = meas, ref, kick, cmd
        tel_log[k] = ctrl.telemetry
        if adaptive:
            theta_g_log[k] = ctrl.theta_g
            for i in range(3):
                theta_f_log[i][k] = ctrl.theta_f[i]
        if left_the_envelope(meas):
            diverged = True
            n = k + 1
            break
        plant.set_motor_commands(cmd)
        plant.advance(period_s)
        if onboard is not None:
            velocity = plant.state().velocity_ned_mps
            acceleration = (velocity - previous_velocity) / period_s
            previous_velocity = velocity
    wall = time.perf_counter() - start
    return RunRecord(
        scenario=scenario.name, controller=controller, plant=plant_fidelity, period_s=period_s,
        time_s=np.arange(n) * period_us / 1e6, measurement=meas_log[:n], reference=ref_log[:n],
        kick=kick_log[:n], motor_commands=cmd_log[:n], channel_telemetry=tel_log[:n],
        theta_g=theta_g_log[:n], theta_f=[t[:n] for t in theta_f_log], wall_time_s=wall,
        diverged=diverged, truth=None if onboard is None else truth_log[:n],
        startup_wall_s=startup_wall_s,
    )


def _estimate(onboard: Estimator, suite: SensorSuite, home: Home, time_us: int, plant: Plant,
              acceleration: np.ndarray, effects: SensorEffects) -> np.ndarray:
    """The sensors read the plant; the estimator takes them as the autopilot's link does:
    the messages packed and parsed (float32 fields, integer scalings), so a lockstep run
    through the processes gives the same numbers."""
    readings, fix = suite.sample(time_us, plant.state(), acceleration, effects)
    if fix is not None:
        position, velocity, fix_type, satellites = fix_from_hil_gps(_over_the_link(
            gps_message(fix)), home)
        onboard.gps(time_us, GpsFix(position, velocity, fix_type, satellites))
    gyro, accel, baro_alt_amsl_m, mag = imu_from_hil_sensor(_over_the_link(
        sensor_message(readings)))
    onboard.imu(time_us, gyro, accel, baro_alt_amsl_m - home.alt_amsl_m, mag)
    return onboard.measurement()


_LINK = new_mavlink(1, 51)


def _over_the_link(msg):
    return _LINK.parse_buffer(msg.pack(_LINK))[0]
