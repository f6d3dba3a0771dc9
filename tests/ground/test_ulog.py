"""PX4 logs in (ground/ulog/): identification data from logs this project writes with
pyulog's writer (tests/ulog_logs.py: the quad X 500's excitation flown in process, logged
as PX4 1.15 and 1.12 log it), checked against the run's own arrays through the formulas
``ivfm identify --log`` uses; the airborne spans, the clock, the motor model, the version
aliases; ``ivfm ulog info``; the draft airframe; bad logs refused with the problem named."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

import numpy as np
import pytest

from autopilot.identification.dataset import Dataset
from contracts.airframe import airframe_from_spec, controller_inputs, residual_rotor_speed
from contracts.airframe import rotor_speeds as contract_rotor_speeds
from contracts.airframe_file import AirframeError, read_airframe
from contracts.frames import (
    body_rates_from_euler_rates,
    euler_from_quat,
    euler_rates_from_body_rates,
    quat_from_euler,
)
from ground.cli.main import main
from ground.ulog.airframe_draft import draft_airframe
from ground.ulog.clock import (
    airborne_spans,
    euler_accelerations,
    euler_from_quaternions,
    euler_rates,
)
from ground.ulog.identification import MotorModel, identification_data, rotor_speeds
from ground.ulog.info import format_info, log_info
from ground.ulog.read import read_log
from tests.ulog_logs import (
    LogBuilder,
    flight_log,
    lockstep_flight,
    timeline,
)

X500 = read_airframe("quad-x-500")
AF = airframe_from_spec(X500)


@pytest.fixture(scope="module")
def flight():
    return lockstep_flight()


@pytest.fixture(scope="module")
def logs(tmp_path_factory, flight):
    """The flight as PX4 1.15 logs it (with and without its derivative of the rates) and
    as PX4 1.12 did."""
    folder = tmp_path_factory.mktemp("ulogs")
    return {"1.15": flight_log(folder / "x500-1.15.ulg", flight),
            "1.15-no-derivative": flight_log(folder / "x500-nd.ulg", flight,
                                             acceleration=False),
            "1.12": flight_log(folder / "x500-1.12.ulg", flight, "1.12")}


def log_dataset(flight, skip_s: float = 2.0) -> Dataset:
    """What ``ivfm identify --log`` makes of the same flight (dataset_from_log's formulas,
    row by row through the compiled airframe functions): forward differences of the Euler
    rates, the inputs of the commands as the plant maps them."""
    t = flight.time_s
    acc = np.diff(flight.euler_rate_rad_s, axis=0) / np.diff(t)[:, None]
    rows = []
    for k in np.flatnonzero(t[:-1] >= t[0] + skip_s):
        w = contract_rotor_speeds(flight.motor_commands[k], AF)
        _uz, *u = controller_inputs(w, np.ones(4), AF)
        rows.append([t[k], *flight.euler_rad[k], *flight.euler_rate_rad_s[k],
                     residual_rotor_speed(w, AF), *u, *acc[k]])
    rows = np.array(rows)
    names = ["time_s", "phi_rad", "theta_rad", "psi_rad", "phi_rate_rad_s",
             "theta_rate_rad_s", "psi_rate_rad_s", "w_r_rad_s", "u_phi_n", "u_theta_n",
             "u_psi_nm", "phi_acc_rad_s2", "theta_acc_rad_s2", "psi_acc_rad_s2"]
    return Dataset({n: rows[:, j] for j, n in enumerate(names)})


# -- identification data ---------------------------------------------------------------------

def test_a_1_15_log_gives_the_runs_own_data_to_float32(logs, flight):
    """Without PX4's derivative, trimmed as --log skips (2 s at the start, none at the end)
    and unfiltered, the log's data is the run's: every column to the float32 the log
    stores (Euler angles from the quaternion, rates from the body rates, the inputs from
    thrust fractions c^2 of the speed map)."""
    data = identification_data(logs["1.15-no-derivative"], X500, trim_s=(2.0, 0.0),
                               cutoff_hz=0.0)
    mine, ref = data.dataset, log_dataset(flight)
    line = timeline(flight)
    assert mine.n_rows == ref.n_rows == 3999
    assert np.allclose(data.spans, [(line.takeoff_s + 2.0, line.takeoff_s + 41.98)],
                       rtol=0, atol=1e-9)
    assert np.max(np.abs(mine.column("time_s") - line.takeoff_s - ref.column("time_s"))) < 1e-9
    tolerances = {"phi_rad": 1e-7, "theta_rad": 1e-7, "psi_rad": 1e-7,
                  "phi_rate_rad_s": 3e-7, "theta_rate_rad_s": 3e-7, "psi_rate_rad_s": 3e-7,
                  "w_r_rad_s": 1e-4, "u_phi_n": 2e-6, "u_theta_n": 2e-6, "u_psi_nm": 1e-7,
                  "phi_acc_rad_s2": 5e-5, "theta_acc_rad_s2": 5e-5, "psi_acc_rad_s2": 5e-5}
    for name, tol in tolerances.items():
        assert np.max(np.abs(mine.column(name) - ref.column(name))) < tol, name
    b = AF.input_gains
    for j, ch in enumerate(("phi", "theta", "psi")):  # f = acc - b U, as --log writes it
        u = mine.column(("u_phi_n", "u_theta_n", "u_psi_nm")[j])
        assert np.array_equal(mine.column(f"f_{ch}"), mine.column(f"{ch}_acc_rad_s2") - b[j] * u)
    assert data.sources["motors"] == "actuator_motors.control[0..3]: thrust fractions"
    assert data.sources["acceleration"].startswith("differentiated (forward differences")
    assert data.sources["acceleration"].endswith("not filtered")


def test_a_simulators_log_gives_the_runs_rows_exactly(tmp_path, flight):
    """A log as a simulator writes a run (stamps from 0 us, armed and in the air from its
    first sample to its last, no derivative of the rates): the start trimmed 2 s as --log
    skips, the end kept (no landing to trim, the last sample taken), and unfiltered, the
    rows are --log's, one for one."""
    path = flight_log(tmp_path / "sim.ulg", flight, simulator=True, acceleration=False)
    log = read_log(path)
    assert log.ulog.start_timestamp == 0 and log.series("armed").time_s[0] == 0.0
    data = identification_data(path, X500, cutoff_hz=0.0)
    mine, ref = data.dataset, log_dataset(flight)
    assert mine.n_rows == ref.n_rows == 3999
    assert np.max(np.abs(mine.column("time_s") - ref.column("time_s"))) < 1e-9
    for name in ("phi_rad", "psi_rate_rad_s", "u_theta_n", "theta_acc_rad_s2"):
        assert np.max(np.abs(mine.column(name) - ref.column(name))) < 5e-5, name
    assert airborne_spans(log).ends_airborne


def test_px4s_derivative_is_taken_when_logged(logs, flight):
    """1.15's vehicle_angular_velocity.xyz_derivative (here forward differences of the
    body rates) turned into Euler accelerations, E w' + E' w: within 0.11 rad/s^2 (0.01
    RMS) of the forward differences of the Euler rates, a first-order difference."""
    data = identification_data(logs["1.15"], X500, trim_s=(2.0, 0.0))
    mine, ref = data.dataset, log_dataset(flight)
    assert mine.n_rows == 4000  # no difference taken: the last instant is kept
    assert "xyz_derivative" in data.sources["acceleration"]
    for ch in ("phi", "theta", "psi"):
        diff = mine.column(f"{ch}_acc_rad_s2")[:-1] - ref.column(f"{ch}_acc_rad_s2")
        assert np.max(np.abs(diff)) < 0.11 and np.sqrt(np.mean(diff**2)) < 0.01, ch


def test_a_1_12_log_reads_through_the_aliases(logs, flight):
    """PX4 1.12's names: actuator_outputs in whole-microsecond PWM (PWM_MAIN_MIN/MAX, the
    thrust model THR_MDL_FAC = 1), no angular acceleration (differentiated, then the
    20 Hz low-pass). The attitude is the same; the rotors within the PWM's 1 us step."""
    data = identification_data(logs["1.12"], X500, trim_s=(2.0, 0.0))
    mine, ref = data.dataset, log_dataset(flight)
    assert data.sources["motors"] == ("actuator_outputs.output[0..3]: PWM 1000-2000 us "
                                      "(PWM_MAIN_MIN/PWM_MAIN_MAX), thrust = f x^2 + (1 - f) x "
                                      "with THR_MDL_FAC = 1")
    assert "Butterworth low-pass at 20 Hz" in data.sources["acceleration"]
    assert np.max(np.abs(mine.column("phi_rad") - ref.column("phi_rad"))) < 1e-7
    # 1 us of 1000 is 1 rad/s of W_max = 1000 rad/s, four rotors: |W_r| error <= 2 rad/s.
    assert np.max(np.abs(mine.column("w_r_rad_s") - ref.column("w_r_rad_s"))) <= 2.0 + 1e-6


def test_the_filter_keeps_what_is_below_its_cutoff(logs):
    """The zero-phase low-pass acts on accelerations and U alike: at 20 Hz on this 100 Hz
    data the accelerations move by less than 5 % RMS of their size, and the relation
    f = acc - b U holds after it as before."""
    raw = identification_data(logs["1.12"], X500, cutoff_hz=0.0).dataset
    smooth = identification_data(logs["1.12"], X500).dataset
    for name in ("phi_acc_rad_s2", "u_phi_n", "u_psi_nm"):
        a, b = raw.column(name), smooth.column(name)
        assert 0 < np.sqrt(np.mean((a - b) ** 2)) < 0.05 * np.sqrt(np.mean(a**2)), name
    b1 = AF.input_gains[0]
    assert np.allclose(smooth.column("f_phi"),
                       smooth.column("phi_acc_rad_s2") - b1 * smooth.column("u_phi_n"))


# -- spans and the clock ---------------------------------------------------------------------

def test_only_the_armed_airborne_spans_are_taken(logs, flight):
    """Armed at 2 s, airborne 3-45 s, landed, disarmed at 46 s: one span, trimmed 2 s at
    each end by default; nothing from the ground (where actuator_motors is NaN)."""
    line = timeline(flight)
    spans = airborne_spans(read_log(logs["1.15"]))
    assert spans.armed_s == pytest.approx(line.disarmed_s - line.armed_s, abs=1e-9)
    assert spans.airborne_s == pytest.approx(line.landing_s - line.takeoff_s, abs=1e-9)
    assert spans.spans == ((line.takeoff_s + 2.0, line.landing_s - 2.0),)
    assert not spans.ends_airborne
    t = identification_data(logs["1.15"], X500).dataset.column("time_s")
    assert t[0] == pytest.approx(line.takeoff_s + 2.0, abs=1e-9)
    assert t[-1] < line.landing_s - 2.0


def test_a_landing_in_the_middle_makes_two_spans(tmp_path, flight):
    line = timeline(flight)
    path = flight_log(tmp_path / "two.ulg", flight, landed_between=((20.0, 25.0),))
    data = identification_data(path, X500)
    assert np.allclose(data.spans, [(line.takeoff_s + 2.0, 18.0 - 0.01),
                                    (27.0, line.landing_s - 2.0 - 0.01)], rtol=0, atol=1e-9)
    t = data.dataset.column("time_s")
    assert not np.any((t > 18.0) & (t < 27.0))
    assert np.all(np.diff(t) > 0)


def test_a_gap_in_the_rates_cuts_the_span(tmp_path, flight):
    """Nothing is interpolated across a dropout of a signal (5 of its intervals)."""
    path = flight_log(tmp_path / "gap.ulg", flight, rates_gap=(20.0, 20.5))
    data = identification_data(path, X500)
    t = data.dataset.column("time_s")
    assert len(data.spans) == 2
    assert np.max(t[t < 20.25]) == pytest.approx(19.99, abs=1e-9)  # [5, 20) and [20.5, 43)
    assert np.min(t[t > 20.25]) == pytest.approx(20.5, abs=1e-9)


def test_slower_topics_are_resampled_on_the_rates_clock(tmp_path, flight):
    """Attitude at 25 Hz (slerp between its samples), motors at 10 Hz (held: each instant
    takes the last output before it), on the body rates' 100 Hz clock."""
    path = flight_log(tmp_path / "slow.ulg", flight, attitude_every=4, motors_every=10)
    data = identification_data(path, X500, trim_s=(2.0, 1.0), cutoff_hz=0.0)
    assert data.period_s == 0.01
    ds, line = data.dataset, timeline(flight)
    k = np.round((ds.column("time_s") - line.takeoff_s) / 0.01).astype(int)
    exact = k % 4 == 0
    phi_error = np.abs(ds.column("phi_rad") - flight.euler_rad[k, 0])
    assert np.max(phi_error[exact]) < 1e-7  # at its own samples: the sample
    assert np.max(phi_error) < 2e-3  # between them: the great-circle arc (measured 1.1e-3)
    held = (k // 10) * 10  # the flight's step logged last (the log starts on a multiple)
    w = AF.max_rad_s * np.sqrt(np.float32(flight.motor_commands[held] ** 2).astype(float))
    assert np.allclose(ds.column("w_r_rad_s"), w @ AF.spin, rtol=0, atol=1e-9)


# -- frames and the motor model --------------------------------------------------------------

def test_the_vectorised_frames_are_the_compiled_ones():
    rng = np.random.default_rng(1)
    euler = rng.uniform([-1.2, -1.2, -3.0], [1.2, 1.2, 3.0], (50, 3))
    body = rng.normal(size=(50, 3))
    quats = np.array([quat_from_euler(*e) for e in euler])
    assert np.allclose(euler_from_quaternions(quats),
                       [euler_from_quat(q) for q in quats], rtol=0, atol=1e-15)
    assert np.allclose(euler_rates(euler, body),
                       [euler_rates_from_body_rates(*e[:2], *w) for e, w in
                        zip(euler, body, strict=True)], rtol=0, atol=1e-12)


def test_euler_accelerations_are_the_derivative_of_the_euler_rates():
    """E(eta) w' + dE/dt w against the second derivative of a smooth attitude eta(t),
    with w the body rates of its Euler rates and w' their central difference."""
    def eta(t):
        return np.array([0.5 * np.sin(t), 0.4 * np.cos(1.3 * t), 0.2 * t + 0.1 * np.sin(2 * t)])

    def eta_dot(t):
        return np.array([0.5 * np.cos(t), -0.52 * np.sin(1.3 * t), 0.2 + 0.2 * np.cos(2 * t)])

    def eta_ddot(t):
        return np.array([-0.5 * np.sin(t), -0.676 * np.cos(1.3 * t), -0.4 * np.sin(2 * t)])

    def body(t):
        e, d = eta(t), eta_dot(t)
        return body_rates_from_euler_rates(e[0], e[1], *d)

    h = 1e-5
    for t in (0.1, 0.7, 2.3):
        w = body(t)[None, :]
        dw = ((body(t + h) - body(t - h)) / (2 * h))[None, :]
        e = eta(t)[None, :]
        rates = euler_rates(e, w)
        assert np.allclose(rates[0], eta_dot(t), rtol=0, atol=1e-14)
        assert np.allclose(euler_accelerations(e, rates, w, dw)[0], eta_ddot(t), rtol=0,
                           atol=1e-8)


def test_the_motor_model_inverts_the_command_maps():
    """A speed-map command c is a thrust fraction c^2 (PX4's actuator_motors) or a PWM
    signal c with THR_MDL_FAC = 1; a thrust-map command c is the thrust fraction c, or the
    signal c with THR_MDL_FAC = 0: either way the rotor speeds of contracts.airframe."""
    c = np.linspace(0.0, 1.0, 11)[:, None] * np.ones(4)
    speed, thrust = AF, AF._replace(thrust_command_map=True)
    pwm = 1000.0 + 1000.0 * c
    for af, fraction, factor in ((speed, c**2, 1.0), (thrust, c, 0.0)):
        expected = np.array([contract_rotor_speeds(row, af) for row in c])
        assert np.allclose(rotor_speeds(MotorModel("thrust", factor).thrust_fraction(fraction),
                                        af), expected, rtol=1e-15, atol=1e-12)
        model = MotorModel("pwm", factor, (1000.0,) * 4, (2000.0,) * 4)
        assert np.allclose(rotor_speeds(model.thrust_fraction(pwm), af), expected,
                           rtol=1e-15, atol=1e-12)
    half = MotorModel("pwm", 0.5, (1000.0,) * 4, (2000.0,) * 4)
    assert half.thrust_fraction(np.full((1, 4), 1500.0))[0, 0] == 0.375  # 0.5 x/2 + 0.5 x^2/...
    assert np.all(half.thrust_fraction(np.full((1, 4), 900.0)) == 0.0)  # disarmed: no thrust


def test_old_names_are_found_where_new_ones_are_missing(tmp_path):
    """Before 1.10 the body rates were vehicle_attitude.rollspeed etc.; PWM_MIN/PWM_MAX
    (1.11) stand in for an unset (-1) PWM_MAIN_MINn."""
    b = LogBuilder()
    t = np.arange(0, 100) * 10_000 + 5_000_000
    b.topic("vehicle_attitude", t, {"rollspeed": ("float", np.full(100, 0.5)),
                                    "pitchspeed": ("float", np.zeros(100)),
                                    "yawspeed": ("float", np.zeros(100)),
                                    "q": ("float", np.tile([1.0, 0, 0, 0], (100, 1)))})
    b.parameters({"PWM_MAIN_MIN1": -1, "PWM_MIN": 1075, "PWM_MAX": 1950})
    log = read_log(b.write(tmp_path / "old.ulg"))
    rates = log.series("rates")
    assert rates.label == "vehicle_attitude.rollspeed, pitchspeed, yawspeed"
    assert np.all(rates.values[:, 0] == 0.5)
    assert log.parameter("pwm_min", 1) == ("PWM_MIN", 1075.0)
    assert log.parameter("pwm_max", 1) == ("PWM_MAX", 1950.0)


# -- ivfm ulog info --------------------------------------------------------------------------

def test_info_says_what_the_log_holds(logs):
    text = format_info(log_info(logs["1.12"], X500))
    lines = text.splitlines()
    assert lines[0] == f"{logs['1.12']}: PX4 v1.12.3 (01234567), PX4_SITL, 47.0 s"
    assert lines[1] == "vehicle: MAV_TYPE 2 (QUADROTOR), 4 rotors (MAV_TYPE 2), SYS_AUTOSTART 4001"
    assert lines[2] == "flight: armed 44.0 s, airborne 42.0 s; 38.0 s in 1 span after trimming"
    assert "  motors          100.0 Hz  actuator_outputs.output[0..3] (4700 samples)" in lines
    assert any(line.startswith("  acceleration  missing: looked for vehicle_angular_velocity"
                               ".xyz_derivative[0..2] (1.13 and later); "
                               "vehicle_angular_acceleration.xyz[0..2] (1.10 to 1.12)")
               for line in lines)
    assert "identification (ivfm identify --ulog): ready, the flight covers the envelope" in lines
    assert ("draft airframe (ivfm airframe from-ulog): the log lacks rotor positions and "
            "spins (no CA_ROTOR* parameters: PX4 before 1.13) (marked TO_FILL, with the "
            "inertia)") in lines
    info = log_info(logs["1.12"], X500)
    assert [c.column for c in info.reach] == ["phi_rad", "theta_rad", "phi_rate_rad_s",
                                              "theta_rate_rad_s", "psi_rate_rad_s"]
    assert all(c.covered for c in info.reach)


def test_info_without_an_airframe_gives_raw_ranges_and_names_what_is_missing(tmp_path, flight):
    path = flight_log(tmp_path / "no-motors.ulg", flight, drop_topics=("actuator_motors",))
    info = log_info(path)
    assert info.reach is None and set(info.ranges) == {
        "phi_rad", "theta_rad", "phi_rate_rad_s", "theta_rate_rad_s", "psi_rate_rad_s"}
    lo, q0, q1, hi = info.ranges["phi_rad"]
    assert lo <= q0 < q1 <= hi and hi == pytest.approx(0.973, abs=0.001)
    assert info.lacks_identification == [
        "motor outputs: looked for actuator_motors.control[0..3] (1.13 and later (thrust "
        "fraction 0..1)); actuator_outputs.output[0..3] (every version (PWM [us]))"]


# -- the draft airframe ----------------------------------------------------------------------

def test_the_draft_of_a_quad_x_log_reproduces_its_geometry(logs, tmp_path):
    """Rotor positions and spins exactly (the float32 parameters written back as typed),
    the coefficients to the float32 of the hover thrust; only the inertia to fill."""
    draft = draft_airframe(logs["1.15"], X500.mass_kg, 1000.0, "x500-draft")
    assert draft.to_fill == ["inertia_kgm2"]
    data = tomllib.loads(draft.text)
    assert data["draft"]["to_fill"] == ["inertia_kgm2"]
    assert data["command_map"] == "speed"
    for mine, theirs in zip(data["rotor"], X500.rotors, strict=True):
        assert tuple(mine["position_m"]) == theirs.position_m
        assert {"cw": 1.0, "ccw": -1.0}[mine["spin"]] == theirs.spin
        assert mine["max_rad_s"] == theirs.max_rad_s
        assert mine["thrust_coeff_ns2"] == pytest.approx(theirs.thrust_coeff_ns2, rel=1e-6)
        assert mine["moment_coeff_nms2"] == pytest.approx(theirs.moment_coeff_nms2, rel=1e-6)
    path = tmp_path / "draft.toml"
    path.write_text(draft.text)
    with pytest.raises(AirframeError, match=r"a draft airframe: fill in inertia_kgm2 \(each "
                                            r"marked \"TO_FILL\""):
        read_airframe(str(path))
    inertia = "[[0.0217, 0.0, 0.0], [0.0, 0.0217, 0.0], [0.0, 0.0, 0.04]]"
    path.write_text(draft.text.replace('inertia_kgm2 = "TO_FILL"', f"inertia_kgm2 = {inertia}"))
    filled = read_airframe(str(path))
    assert np.allclose(filled.effectiveness(), X500.effectiveness(), rtol=1e-6, atol=0)
    assert filled.command_map == X500.command_map


def test_esc_telemetry_gives_the_top_speed(tmp_path, flight):
    """esc_status rpm (whole rpm, the ESCs in another order than the motors, mapped by
    actuator_function) fitted to W = W_max sqrt(thrust fraction): 1000 rad/s to 1e-5."""
    path = flight_log(tmp_path / "esc.ulg", flight, esc=True)
    draft = draft_airframe(path, X500.mass_kg, None, "esc")
    assert draft.to_fill == ["inertia_kgm2"]
    rotors = tomllib.loads(draft.text)["rotor"]
    assert [r["max_rad_s"] for r in rotors] == pytest.approx([1000.0] * 4, rel=1e-5)
    assert "max_rad_s = 999.998  # esc_status rpm fitted to W = W_max sqrt(thrust), " \
           "R^2 >= 1.00" in draft.text.splitlines()


def test_rehearse_refuses_the_draft_naming_what_to_fill(logs, tmp_path, capsys):
    draft = tmp_path / "draft.toml"
    assert main(["airframe", "from-ulog", str(logs["1.12"]), "--mass-kg", "2.0",
                 "--out", str(draft)]) == 0
    printed = capsys.readouterr().out
    assert printed.startswith(f"wrote {draft}\nfill in (marked TO_FILL): inertia_kgm2, "
                              "rotor[1].position_m, rotor[1].spin, rotor[1].thrust_coeff_ns2")
    out = tmp_path / "rehearsal"
    assert main(["rehearse", "--airframe", str(draft), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"ivfm: error: airframe file {draft}: a draft airframe: fill in "
                          "inertia_kgm2, rotor[1].position_m, rotor[1].spin, ")
    assert "rotor[4].max_rad_s (each marked \"TO_FILL\"" in err
    assert not out.exists()
    # And it does not overwrite a file that is there.
    assert main(["airframe", "from-ulog", str(logs["1.12"]), "--mass-kg", "2.0",
                 "--out", str(draft)]) == 2
    assert "exists (a filled-in airframe?)" in capsys.readouterr().err


@pytest.mark.parametrize("parameters, message", [
    ({"CA_ROTOR_COUNT": 6}, "CA_ROTOR_COUNT says 6 rotors: this stack flies quadrotors"),
    ({"CA_AIRFRAME": 2}, r"CA_AIRFRAME = 2 \(Standard VTOL\): this stack flies multicopters"),
    ({"CA_ROTOR1_AX": 0.3}, r"rotor 2 is tilted; this stack's rotors push along -z"),
    ({"CA_ROTOR2_KM": 0.0160234}, r"CA_ROTOR0-3_KM: rotors 1-4 spin ccw, ccw, ccw, cw: "
                                  r"a quadrotor needs two of each"),
    ({"CA_ROTOR1_PX": 0.175, "CA_ROTOR1_PY": 0.175}, "rank deficient"),  # two in one place
])
def test_an_allocation_this_stack_cannot_fly_is_refused(tmp_path, flight, capsys, parameters,
                                                        message):
    path = flight_log(tmp_path / "bad.ulg", flight, parameters=parameters)
    code = main(["airframe", "from-ulog", str(path), "--mass-kg", "2", "--out",
                 str(tmp_path / "d.toml")])
    err = capsys.readouterr().err
    assert code == 2 and err.startswith("ivfm: error: ") and "Traceback" not in err
    assert re.search(message, err), err
    assert not (tmp_path / "d.toml").exists()


# -- bad logs --------------------------------------------------------------------------------

def _identify(path: Path, tmp_path: Path, capsys) -> str:
    code = main(["identify", "--ulog", str(path), "--airframe", "quad-x-500", "--out",
                 str(tmp_path / "m.json")])
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err, err
    assert not (tmp_path / "m.json").exists()
    return err.splitlines()[-1]


def test_bad_files_are_refused_with_the_problem_named(tmp_path, logs, capsys):
    empty = tmp_path / "empty.ulg"
    empty.write_bytes(b"")
    assert _identify(empty, tmp_path, capsys) == f"ivfm: error: {empty}: empty file, not a ULog"
    wrong = tmp_path / "wrong.ulg"
    wrong.write_bytes(b"MCAP0\r\n" + bytes(100))
    assert _identify(wrong, tmp_path, capsys) == (
        f"ivfm: error: {wrong}: not a ULog file (it does not start with ULog's magic bytes "
        "'ULog' 01 12 35)")
    header = tmp_path / "header.ulg"
    header.write_bytes(logs["1.15"].read_bytes()[:12])
    assert _identify(header, tmp_path, capsys) == (
        f"ivfm: error: {header}: not a readable ULog (ULogException: Invalid file format "
        "(Header too short))")
    cut = tmp_path / "cut.ulg"
    cut.write_bytes(logs["1.15"].read_bytes()[:600])  # within the definitions
    assert _identify(cut, tmp_path, capsys) == (
        f"ivfm: error: {cut}: the log holds no data (cut short in its header?)")
    missing = tmp_path / "missing.ulg"
    missing_path = tmp_path / "nowhere.ulg"
    assert _identify(missing_path, tmp_path, capsys).startswith(
        f"ivfm: error: {missing_path}: cannot read (No such file or directory)")
    del missing


def test_a_log_cut_in_flight_is_read_to_its_end_and_said(tmp_path, logs, capsys):
    data = logs["1.15"].read_bytes()
    cut = tmp_path / "cut.ulg"
    cut.write_bytes(data[: int(len(data) * 0.6)])
    result = identification_data(cut, X500)
    assert "the log ends with the vehicle in the air (cut short?)" in result.notes[0]
    assert result.dataset.n_rows > 1000


def test_missing_topics_are_named_with_every_alias(tmp_path, flight, capsys):
    path = flight_log(tmp_path / "no-land.ulg", flight, drop_topics=("vehicle_land_detected",
                                                                      "actuator_motors"))
    assert _identify(path, tmp_path, capsys) == (
        f"ivfm: error: {path}: cannot identify from this log: the log has no motor outputs: "
        "looked for actuator_motors.control[0..3] (1.13 and later (thrust fraction 0..1)); "
        "actuator_outputs.output[0..3] (every version (PWM [us])); the log has no land "
        "detector state: looked for vehicle_land_detected.landed (every version)")


def test_nan_inside_a_span_is_refused_and_outside_ignored(tmp_path, flight, capsys):
    """PX4 logs NaN for a motor that is off: on the ground (the fixture's disarmed phases)
    it is no matter; in the air it is refused, naming the field and time."""
    path = flight_log(tmp_path / "nan.ulg", flight, nan_at=("control[2]", 20.0))
    assert _identify(path, tmp_path, capsys) == (
        f"ivfm: error: {path}: actuator_motors.control[2] is nan at 20.000 s, inside the "
        "airborne span 5.00-43.00 s")


def test_a_log_that_never_flew_is_refused(tmp_path, flight, capsys):
    line = timeline(flight)
    path = flight_log(tmp_path / "ground.ulg", flight,
                      landed_between=((line.takeoff_s, line.landing_s),))
    assert _identify(path, tmp_path, capsys) == (
        f"ivfm: error: {path}: the vehicle was never armed and airborne for more than 4 s "
        "(armed 44.0 s, airborne 0.0 s by vehicle_status and vehicle_land_detected)")
