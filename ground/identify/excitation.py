"""The paper's excitation data: an attitude flight of the simulated quadrotor, recorded as
input-output samples for identification (4000 samples at T = 0.01 s, 5 % output noise).

The vehicle flies in one process under the SMC baseline, tracking the seeded multisine
attitude references designed for an envelope (``excitation_sines``); the simulator hands
over f_i(x) itself, as in the paper, along with the accelerations and inputs a flight log
would hold.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from autopilot.control.factory import make_controller
from autopilot.identification.dataset import ALL_COLUMNS, CHANNEL_INPUT, Dataset
from autopilot.trajectories import evaluate_multisine, excitation_sines
from contracts.airframe import (
    Airframe,
    attitude_drift,
    controller_inputs,
    hover_rotor_speeds,
    residual_rotor_speed,
    rotor_momentum,
    rotor_speeds,
)
from contracts.airframe_file import PAPER_ENVELOPE, Envelope
from contracts.vectors import (
    MEASUREMENT,
    REF_EULER,
    REF_EULER_ACC,
    REF_EULER_RATE,
    REF_POS,
    REF_SIZE,
)
from ground.record.run_files import control_records
from sitl.plant import Plant

WARM_UP_SAMPLES = 200  # flown, not recorded: the start-up transient is not excitation
# The dataset's outputs: the paper adds noise to every one.
OUTPUT_COLUMNS = ("phi_acc_rad_s2", "theta_acc_rad_s2", "psi_acc_rad_s2", "f_phi", "f_theta",
                  "f_psi")


def _columns(rows: list[dict[str, float | np.ndarray]]) -> dict[str, np.ndarray]:
    return {name: np.array([row[name] for row in rows]) for name in ALL_COLUMNS}


def _add_output_noise(columns: dict[str, np.ndarray], noise_fraction: float,
                      rng: np.random.Generator) -> None:
    """Gaussian noise of ``noise_fraction`` of each output's amplitude max |y|."""
    noise = rng.normal(size=(len(columns["time_s"]), len(OUTPUT_COLUMNS)))
    for i, name in enumerate(OUTPUT_COLUMNS):
        columns[name] = columns[name] + noise[:, i] * noise_fraction * np.max(
            np.abs(columns[name]))


def _inputs(commands: np.ndarray, airframe: Airframe) -> tuple[np.ndarray, float, float]:
    """(U_phi, U_theta, U_psi), W_r and h_r of motor commands, as the plant maps them."""
    rotor_rad_s = rotor_speeds(commands, airframe)
    _u_z, *u = controller_inputs(rotor_rad_s, np.ones(4), airframe)
    return (np.array(u), residual_rotor_speed(rotor_rad_s, airframe),
            rotor_momentum(rotor_rad_s, airframe))


def _sample(t_s: float, euler_rad: np.ndarray, euler_rate_rad_s: np.ndarray, w_r: float,
            u: np.ndarray, acc: np.ndarray, f: np.ndarray) -> dict[str, float]:
    """One dataset row by column name."""
    row = {"time_s": t_s, "w_r_rad_s": w_r}
    for i, ch in enumerate(("phi", "theta", "psi")):
        row[f"{ch}_rad"] = euler_rad[i]
        row[f"{ch}_rate_rad_s"] = euler_rate_rad_s[i]
        row[CHANNEL_INPUT[ch]] = u[i]
        row[f"{ch}_acc_rad_s2"] = acc[i]
        row[f"f_{ch}"] = f[i]
    return row


MIN_SAMPLES = 20  # fewer cannot fit the clusters


def excitation_dataset(
    airframe: Airframe,
    n_samples: int = 4000,
    period_s: float = 0.01,
    noise_fraction: float = 0.05,
    seed: int = 0,
    progress: Callable[[float], None] | None = None,
    envelope: Envelope = PAPER_ENVELOPE,
) -> Dataset:
    """Fly the excitation designed for ``envelope`` and return the samples (noise: fraction
    of each output's amplitude max |y|, Gaussian, seeded). ``progress`` hears the sim time
    [s] every tenth of a sim second."""
    if n_samples < MIN_SAMPLES:
        raise ValueError(f"n_samples must be at least {MIN_SAMPLES}, got {n_samples}")
    if not 0.0 <= noise_fraction < 1.0:
        raise ValueError(f"noise_fraction must be in [0, 1), got {noise_fraction}")
    rng = np.random.default_rng(seed)
    sines = excitation_sines(rng, envelope)
    plant = Plant(airframe, "paper", position_ned_m=(0.0, 0.0, -10.0),
                  rotor_rad_s=hover_rotor_speeds(airframe))
    controller = make_controller("smc", airframe, period_s)
    rows = []
    b = airframe.input_gains
    ref = np.zeros(REF_SIZE)
    ref[REF_POS + 2] = -10.0
    progress_every = max(1, round(0.1 / period_s))
    for k in range(-WARM_UP_SAMPLES, n_samples):
        t = k * period_s
        if progress is not None and k % progress_every == 0 and k >= 0:
            progress(t)
        for axis in range(3):
            ref[REF_EULER + axis], ref[REF_EULER_RATE + axis], ref[REF_EULER_ACC + axis] = (
                evaluate_multisine(sines[axis], t))
        meas = plant.true_measurement()
        commands = controller.step(meas, ref, False)
        u, w_r, h_r = _inputs(commands, airframe)
        rates = meas[MEASUREMENT.euler_rate_rad_s]
        f = np.array(attitude_drift(rates[0], rates[1], rates[2], h_r, airframe))
        if k >= 0:
            rows.append(_sample(t, meas[MEASUREMENT.euler_rad], rates, w_r, u, f + b * u, f))
        plant.set_motor_commands(commands)
        plant.advance(period_s)
    columns = _columns(rows)
    _add_output_noise(columns, noise_fraction, rng)
    return Dataset(columns,
                   source=f"excitation(seed={seed}, n={n_samples}, noise={noise_fraction}, "
                          f"envelope={envelope.attitude_rad:g} rad, {envelope.rate_rad_s:g} rad/s)")


def dataset_from_log(log: Path, vehicle: int, airframe: Airframe, skip_s: float = 2.0,
                     noise_fraction: float = 0.0, seed: int = 0) -> Dataset:
    """Identification samples from a logged flight (the autopilot's control records).

    Attitude and Euler rates are the logged measurement; the inputs follow from the logged
    motor commands as the plant maps them; the Euler accelerations are forward differences
    of the logged rates (the command of step k acts over [t_k, t_k+1]); and
    f_i = acceleration - b_i u_i, the paper's drift the IVFM learns.
    """
    r = control_records(log, vehicle)
    if r["missing_count"]:
        raise ValueError(f"the log lacks {r['missing_count']} control records of vehicle "
                         f"{vehicle}; identification needs an unbroken flight")
    t = r["sim_time_us"] / 1e6
    keep = t >= t[0] + skip_s
    meas, commands = r["measurement"], r["motor_commands"]
    if np.count_nonzero(keep) < 21:
        raise ValueError(f"the log has {np.count_nonzero(keep)} samples after {skip_s:g} s; "
                         f"identification needs at least 21")
    rates = meas[:, MEASUREMENT.euler_rate_rad_s]
    acc = np.diff(rates, axis=0) / np.diff(t)[:, None]
    b = airframe.input_gains
    rows = []
    for k in np.flatnonzero(keep[:-1]):
        u, w_r, _h_r = _inputs(commands[k], airframe)
        rows.append(_sample(t[k], meas[k, MEASUREMENT.euler_rad], rates[k], w_r, u, acc[k],
                            acc[k] - b * u))
    columns = _columns(rows)
    if noise_fraction > 0:
        _add_output_noise(columns, noise_fraction, np.random.default_rng(seed))
    return Dataset(columns, source=f"log({log}, vehicle {vehicle}, {len(rows)} samples)")
