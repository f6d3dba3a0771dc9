"""The paper's excitation data: an attitude flight of the simulated quadrotor, recorded as
input-output samples for identification (4000 samples at T = 0.01 s, 5 % output noise).

The vehicle flies in one process under the SMC baseline, tracking random multi-sine
attitude references (seeded); the simulator hands over f_i(x) itself, as in the paper,
along with the accelerations and inputs a flight log would hold.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from autopilot.control.factory import make_controller
from autopilot.identification.dataset import Dataset
from autopilot.reference import (
    REF_EULER,
    REF_EULER_ACC,
    REF_EULER_RATE,
    REF_POS,
    REF_SIZE,
    evaluate_multisine,
    excitation_sines,
)
from contracts.airframe import Airframe, hover_rotor_speed_rps, paper_attitude_drift, rotor_forces
from sitl.plant import Plant

DATASET_COLUMNS = ("time_s", "phi_rad", "theta_rad", "psi_rad", "phi_rate_rps",
                   "theta_rate_rps", "psi_rate_rps", "w_r_rps", "u_phi_n", "u_theta_n",
                   "u_psi_nm", "phi_acc_rps2", "theta_acc_rps2", "psi_acc_rps2", "f_phi",
                   "f_theta", "f_psi")
WARM_UP_SAMPLES = 200  # flown, not recorded: the start-up transient is not excitation


def excitation_dataset(
    airframe: Airframe,
    n_samples: int = 4000,
    period_s: float = 0.01,
    noise_fraction: float = 0.05,
    seed: int = 0,
) -> Dataset:
    """Fly the excitation and return the samples (noise: fraction of each output's
    amplitude max |y|, Gaussian, seeded)."""
    if n_samples < 20:
        raise ValueError(f"n_samples must be at least 20, got {n_samples}")
    if not 0.0 <= noise_fraction < 1.0:
        raise ValueError(f"noise_fraction must be in [0, 1), got {noise_fraction}")
    rng = np.random.default_rng(seed)
    sines = excitation_sines(rng)
    plant = Plant(airframe, "paper", position_ned_m=(0.0, 0.0, -10.0),
                  rotor_rps=hover_rotor_speed_rps(airframe))
    controller = make_controller("smc", airframe, period_s)
    rows = np.zeros((n_samples, 17))
    efficiency = np.ones(4)
    ref = np.zeros(REF_SIZE)
    ref[REF_POS + 2] = -10.0
    for k in range(-WARM_UP_SAMPLES, n_samples):
        t = k * period_s
        for axis in range(3):
            ref[REF_EULER + axis], ref[REF_EULER_RATE + axis], ref[REF_EULER_ACC + axis] = (
                evaluate_multisine(sines[axis], t))
        meas = plant.measurement()
        commands = controller.step(meas, ref, False)
        rotor_rps = commands * airframe.rotor_max_rps
        u_z, u_phi, u_theta, u_psi, w_r = rotor_forces(rotor_rps, efficiency, airframe)
        rates = meas[9:12]
        f = paper_attitude_drift(rates[0], rates[1], rates[2], w_r, airframe)
        acc = (f[0] + airframe.arm_m / airframe.ixx_kgm2 * u_phi,
               f[1] + airframe.arm_m / airframe.iyy_kgm2 * u_theta,
               f[2] + u_psi / airframe.izz_kgm2)
        if k >= 0:
            rows[k] = (t, *meas[6:9], *rates, w_r, u_phi, u_theta, u_psi, *acc, *f)
        plant.set_motor_commands(commands)
        plant.advance(period_s)
    outputs = slice(11, 17)  # accelerations and f: the paper adds noise to every output
    amplitude = np.max(np.abs(rows[:, outputs]), axis=0)
    rows[:, outputs] += rng.normal(size=(n_samples, 6)) * noise_fraction * amplitude
    return Dataset({name: rows[:, i] for i, name in enumerate(DATASET_COLUMNS)},
                   source=f"excitation(seed={seed}, n={n_samples}, noise={noise_fraction})")


def dataset_from_log(log: Path, vehicle: int, airframe: Airframe, skip_s: float = 2.0,
                     noise_fraction: float = 0.0, seed: int = 0) -> Dataset:
    """Identification samples from a logged flight (the autopilot's control records).

    Attitude and Euler rates are the logged measurement; the inputs follow from the logged
    motor commands as the plant maps them; the Euler accelerations are forward differences
    of the logged rates (the command of step k acts over [t_k, t_k+1]); and
    f_i = acceleration - b_i u_i, the paper's drift the IVFM learns.
    """
    from ground.report import control_records

    r = control_records(log, vehicle)
    if len(r["missing"]):
        raise ValueError(f"the log lacks {len(r['missing'])} control records of vehicle "
                         f"{vehicle}; identification needs an unbroken flight")
    t = r["sim_time_us"] / 1e6
    keep = t >= t[0] + skip_s
    meas, commands = r["measurement"], r["motor_commands"]
    if np.count_nonzero(keep) < 21:
        raise ValueError(f"the log has {np.count_nonzero(keep)} samples after {skip_s:g} s; "
                         f"identification needs at least 21")
    period = np.diff(t)
    rates = meas[:, 9:12]
    acc = np.diff(rates, axis=0) / period[:, None]
    rows = []
    efficiency = np.ones(4)
    b = np.array([airframe.arm_m / airframe.ixx_kgm2, airframe.arm_m / airframe.iyy_kgm2,
                  1.0 / airframe.izz_kgm2])
    for k in np.flatnonzero(keep[:-1]):
        _u_z, u_phi, u_theta, u_psi, w_r = rotor_forces(commands[k] * airframe.rotor_max_rps,
                                                        efficiency, airframe)
        u = np.array([u_phi, u_theta, u_psi])
        rows.append((t[k], *meas[k, 6:9], *rates[k], w_r, *u, *acc[k], *(acc[k] - b * u)))
    rows = np.array(rows)
    if noise_fraction > 0:
        rng = np.random.default_rng(seed)
        amplitude = np.max(np.abs(rows[:, 11:17]), axis=0)
        rows[:, 11:17] += rng.normal(size=(len(rows), 6)) * noise_fraction * amplitude
    return Dataset({name: rows[:, i] for i, name in enumerate(DATASET_COLUMNS)},
                   source=f"log({log}, vehicle {vehicle}, {len(rows)} samples)")
