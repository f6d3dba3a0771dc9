"""The identification excitation (docs/mathematics.md, "The excitation"): roll and pitch
with matched spectra, the identifying half covering the envelope, no drift; the coverage
check before a model is written; the envelope from airframe files and the command line."""

from __future__ import annotations

import math
import tomllib
from importlib import resources

import numpy as np
import pytest

from autopilot.identification.coverage import coverage, coverage_metadata, format_coverage
from autopilot.trajectories import (
    EXCITATION_MARGIN,
    EXCITATION_RECORD_S,
    Reference,
    abs_reach,
    excitation_sines,
    tail_reach,
)
from contracts.airframe import PAPER
from contracts.airframe_file import (
    PAPER_ENVELOPE,
    AirframeError,
    Envelope,
    parse_airframe,
    read_airframe,
)
from ground.identify.excitation import excitation_dataset

T = np.arange(0.0, EXCITATION_RECORD_S, 0.01)
HALF = len(T) // 2


def _signals(sines):
    """Angle and rate of one multisine on the record's grid."""
    freqs, phases, amps = sines
    arg = np.outer(T, freqs) + phases
    return np.sin(arg) @ amps, np.cos(arg) @ (amps * freqs)


@pytest.mark.parametrize("seed", range(6))
def test_roll_and_pitch_have_one_spectrum_and_are_uncorrelated(seed):
    roll, pitch, yaw = excitation_sines(np.random.default_rng(seed))
    np.testing.assert_array_equal(roll[0], pitch[0])  # frequencies
    np.testing.assert_array_equal(roll[2], pitch[2])  # amplitudes
    np.testing.assert_allclose(pitch[1] - roll[1], 0.5 * np.pi)  # quadrature
    # Odd harmonics for roll and pitch, even for yaw: no frequency shared.
    assert not set(np.round(roll[0], 9)) & set(np.round(yaw[0], 9))
    (phi, phi_rate), (theta, theta_rate) = _signals(roll), _signals(pitch)
    # Orthogonal over the record (to the sampling of the integral on the 10 ms grid).
    assert abs(np.corrcoef(phi, theta)[0, 1]) < 1e-6
    assert np.std(phi_rate) == pytest.approx(np.std(theta_rate), rel=1e-3)


@pytest.mark.parametrize("envelope", [Envelope(), Envelope(0.7, 1.0, 0.5),
                                      Envelope(0.3, 0.6, 0.2)])
@pytest.mark.parametrize("seed", range(4))
def test_the_identifying_half_of_the_reference_reaches_past_the_envelope(envelope, seed):
    sines = excitation_sines(np.random.default_rng(seed), envelope)
    (phi, phi_rate), (theta, theta_rate) = _signals(sines[0]), _signals(sines[1])
    _yaw, yaw_rate = _signals(sines[2])
    need = EXCITATION_MARGIN * (1.0 - 1e-9)
    # The scale is set by whichever binds: it is met exactly, the other one at least.
    binding = min(min(abs_reach(phi[:HALF]), abs_reach(theta[:HALF])) / envelope.attitude_rad,
                  min(tail_reach(phi_rate[:HALF]), tail_reach(theta_rate[:HALF]))
                  / envelope.rate_rad_s)
    assert binding == pytest.approx(EXCITATION_MARGIN, rel=1e-9)
    assert abs_reach(phi[:HALF]) >= envelope.attitude_rad * need
    assert abs_reach(theta[:HALF]) >= envelope.attitude_rad * need
    assert tail_reach(phi_rate[:HALF]) >= envelope.rate_rad_s * need
    assert tail_reach(theta_rate[:HALF]) >= envelope.rate_rad_s * need
    assert tail_reach(yaw_rate[:HALF]) == pytest.approx(envelope.yaw_rate_rad_s
                                                        * EXCITATION_MARGIN, rel=1e-9)
    if envelope == Envelope():  # attitude and rate bind alike at 1 rad/s
        # The phase set kept overshoots little: no peak past 1.5 x the envelope.
        assert np.max(np.abs(np.r_[phi, theta])) < 1.5 * envelope.attitude_rad
        assert np.max(np.abs(np.r_[phi_rate, theta_rate])) < 1.5 * envelope.rate_rad_s


@pytest.mark.parametrize("seed", range(6))
def test_the_tilt_has_no_constant_velocity_part(seed):
    """The integral of each tilt, the horizontal velocity over g, starts with no constant:
    sum (a_k / w_k) exp(i phi_k) = 0."""
    roll, pitch, _yaw = excitation_sines(np.random.default_rng(seed))
    for freqs, phases, amps in (roll, pitch):
        assert abs(np.sum(amps / freqs * np.exp(1j * phases))) < 1e-12
        integral = np.sum(amps / freqs * (np.cos(phases) - np.cos(np.outer(T, freqs)
                                                                   + phases)), axis=1)
        assert abs(np.mean(integral)) < 0.05 * np.std(integral)


def test_the_design_is_seeded_and_the_reference_flies_it():
    a = excitation_sines(np.random.default_rng(3))
    b = excitation_sines(np.random.default_rng(3))
    c = excitation_sines(np.random.default_rng(4))
    for x, y in zip(a, b, strict=True):
        for u, v in zip(x, y, strict=True):
            np.testing.assert_array_equal(u, v)
    assert not np.array_equal(a[0][1], c[0][1])
    ref = Reference("excitation", seed=3.0)
    assert ref.envelope == Envelope()
    from contracts.vectors import REF_EULER, REF_EULER_RATE
    at = ref.at(7.3)
    freqs, phases, amps = a[0]
    phi = float(np.sin(freqs * 7.3 + phases) @ amps)
    phi_rate = float(np.cos(freqs * 7.3 + phases) @ (amps * freqs))
    assert at[REF_EULER] == pytest.approx(phi, abs=1e-12)
    assert at[REF_EULER_RATE] == pytest.approx(phi_rate, abs=1e-12)
    narrow = Reference("excitation", seed=3.0, amplitude=0.5, rate_rad_s=0.6)
    assert narrow.envelope == Envelope(0.5, 0.6, 0.3)  # yaw: half the rate unless given
    assert Reference("excitation", rate_rad_s=0.6, yaw_rate_rad_s=0.2).envelope \
        == Envelope(1.0, 0.6, 0.2)


@pytest.mark.parametrize("fields, message", [
    ({"amplitude": 0.0}, "attitude envelope"), ({"amplitude": 1.5}, "attitude envelope"),
    ({"rate_rad_s": -1.0}, "rate_rad_s must be in"), ({"rate_rad_s": math.inf}, "finite"),
    ({"rate_rad_s": math.nan}, "finite"), ({"yaw_rate_rad_s": 0.0}, "yaw_rate_rad_s must be"),
    ({"yaw_rate_rad_s": 6.0}, "yaw_rate_rad_s must be in"),
    ({"yaw_rate_rad_s": -math.inf}, "finite"),
])
def test_a_bad_excitation_envelope_is_refused(fields, message):
    with pytest.raises(ValueError, match=message):
        Reference("excitation", **fields)


def test_the_flown_excitation_covers_the_envelope_and_the_check_says_so():
    dataset = excitation_dataset(PAPER, seed=0)
    report = coverage(dataset, Envelope())
    assert [c.column for c in report] == ["phi_rad", "theta_rad", "phi_rate_rad_s",
                                          "theta_rate_rad_s", "psi_rate_rad_s"]
    assert all(c.covered for c in report), format_coverage(report)
    # Matched: roll and pitch rates spread the same (they differed by 70 % before).
    c = dataset.columns
    assert np.std(c["phi_rate_rad_s"]) == pytest.approx(np.std(c["theta_rate_rad_s"]),
                                                         rel=0.02)
    meta = coverage_metadata(Envelope(), report)
    assert meta["covered"] and meta["envelope"]["rate_rad_s"] == 1.0
    # The same data against a wider envelope: not covered, by how much.
    wide = coverage(dataset, Envelope(1.2, 2.0, 1.0))
    rate = next(c for c in wide if c.column == "phi_rate_rad_s")
    assert not rate.covered and rate.reach == pytest.approx(
        min(-rate.low, rate.high) / 2.0)
    text = format_coverage(wide)
    assert "phi_rate_rad_s" in text and "no (" in text
    assert not coverage_metadata(Envelope(1.2, 2.0, 1.0), wide)["covered"]


def test_coverage_needs_a_rate_on_both_sides_and_an_attitude_either_way():
    from autopilot.identification.dataset import REQUIRED_COLUMNS, Dataset

    n = 1000
    cols = {name: np.zeros(n) for name in REQUIRED_COLUMNS}
    cols["time_s"] = np.arange(n) * 0.01
    ramp = np.linspace(0.0, 1.0, n)
    cols["phi_rad"] = 1.2 * ramp  # one way only: enough for an attitude
    cols["theta_rad"] = -1.2 * ramp
    cols["phi_rate_rad_s"] = 1.2 * ramp  # one way only: not enough for a rate
    cols["theta_rate_rad_s"] = 2.4 * ramp - 1.2
    cols["psi_rate_rad_s"] = 1.2 * ramp - 0.6
    report = {c.column: c for c in coverage(Dataset(cols, source="test"), Envelope(),
                                            split=1.0)}
    assert report["phi_rad"].covered and report["theta_rad"].covered
    assert not report["phi_rate_rad_s"].covered
    assert report["theta_rate_rad_s"].covered and report["psi_rate_rad_s"].covered


def test_an_airframe_file_names_its_envelope():
    assert read_airframe("quad-x-500").envelope == (0.7, 1.0, 0.5)
    assert read_airframe("paper").envelope is None
    data = tomllib.loads(resources.files("contracts").joinpath(
        "airframes", "quad-x-500.toml").read_text())
    plain = dict(data)
    plain.pop("envelope")
    # Not part of the fingerprint: a model identified on the vehicle does not depend on it.
    assert parse_airframe(data).fingerprint() == parse_airframe(plain).fingerprint()


@pytest.mark.parametrize("table, message", [
    ({"attitude_rad": 0.7, "rate_rad_s": 1.0}, "exactly attitude_rad, rate_rad_s"),
    ({"attitude_rad": 0.7, "rate_rad_s": 1.0, "yaw_rate_rad_s": 0.5, "x": 1},
     "exactly attitude_rad"),
    ({"attitude_rad": 2.0, "rate_rad_s": 1.0, "yaw_rate_rad_s": 0.5},
     "envelope.attitude_rad must be a number in (0, 1.2]"),
    ({"attitude_rad": 0.7, "rate_rad_s": math.nan, "yaw_rate_rad_s": 0.5},
     "envelope.rate_rad_s must be a number in"),
    ({"attitude_rad": 0.7, "rate_rad_s": 1.0, "yaw_rate_rad_s": 0.0},
     "envelope.yaw_rate_rad_s must be a number in (0"),
    ("fast", "envelope must be a table"),
])
def test_bad_envelope_tables_are_refused(table, message):
    data = tomllib.loads(resources.files("contracts").joinpath(
        "airframes", "quad-x-500.toml").read_text())
    data["envelope"] = table
    with pytest.raises(AirframeError, match=None) as info:
        parse_airframe(data, "airframe file mine.toml")
    assert message in str(info.value) and "mine.toml" in str(info.value), str(info.value)


@pytest.mark.parametrize("text, expected", [
    ("1,1", (1.0, 1.0, 0.5)), ("0.7, 1.0, 0.4", (0.7, 1.0, 0.4)),
])
def test_the_envelope_option_reads_two_or_three_numbers(text, expected):
    from ground.cli.identify import envelope_argument

    assert envelope_argument(text) == expected


@pytest.mark.parametrize("text, message", [
    ("1", "expected ATTITUDE_RAD,RATE_RAD_S"), ("1,2,3,4", "expected"),
    ("0,1", "attitude_rad must be"), ("1,nan", "rate_rad_s must be"),
    ("1,1,-1", "yaw_rate_rad_s must be"), ("2,1", "attitude_rad must be a number in (0, 1.2]"),
])
def test_a_bad_envelope_option_is_refused_naming_the_number(text, message):
    import argparse

    from ground.cli.identify import envelope_argument

    with pytest.raises(argparse.ArgumentTypeError, match=None) as info:
        envelope_argument(text)
    assert message in str(info.value), str(info.value)


def test_a_campaign_identifies_on_the_airframes_envelope():
    """A campaign's model for the quad X 500 is identified for its [envelope], as
    ``ivfm identify`` does: seed 0 is the shipped model, value for value."""
    import json

    from ground.campaign.run import identified_model_json
    from tests.ground.test_new_vehicle import _assert_same_numbers

    mine = json.loads(identified_model_json("quad-x-500", 0))
    shipped = json.loads(resources.files("autopilot.models").joinpath(
        "quad-x-500.json").read_text())
    _assert_same_numbers(mine["channels"], shipped["channels"])


def test_an_excitation_naming_no_envelope_flies_the_airframes(tmp_path):
    """``ivfm run excitation --airframe quad-x-500`` flies the x500's 0.7 rad, not the
    paper's 1 rad; a scenario that names an envelope keeps it on any airframe."""
    from ground.run.flights import Overrides, plan_flight
    from ground.run.processes import RunSettings, vehicle_commands
    from ground.scenario.scenario_file import load_scenario, scenario_by_name

    shipped = scenario_by_name("excitation")
    assert shipped.reference.envelope == PAPER_ENVELOPE
    x500 = plan_flight(shipped, Overrides(airframe="quad-x-500")).scenario
    assert x500.reference.envelope == read_airframe("quad-x-500").envelope
    assert plan_flight(shipped).scenario.reference.envelope == PAPER_ENVELOPE
    # ... and the autopilot is told so
    _sim, autopilot = vehicle_commands(x500, RunSettings("smc", "paper", "quad-x-500"), 1,
                                       "tcp/127.0.0.1:1")
    assert {"amplitude=0.7", "rate_rad_s=1.0", "yaw_rate_rad_s=0.5"} <= set(autopilot)
    text = shipped.source.read_text().replace('kind = "excitation"',
                                              'kind = "excitation"\nrate_rad_s = 0.8')
    (tmp_path / "mine.toml").write_text(text)
    mine = load_scenario(tmp_path / "mine.toml")
    assert plan_flight(mine, Overrides(airframe="quad-x-500")).scenario.reference.envelope \
        == Envelope(1.0, 0.8, 0.4)


@pytest.mark.parametrize("options, envelope", [
    ([], Envelope(0.7, 1.0, 0.5)),  # the airframe file's
    (["amplitude=0.5"], Envelope(0.5, 1.0, 0.5)),  # given: the reference's defaults
    (["rate_rad_s=2", "yaw_rate_rad_s=0.3"], Envelope(1.0, 2.0, 0.3)),
])
def test_the_autopilots_excitation_takes_the_airframes_envelope_unless_given(options,
                                                                             envelope):
    from autopilot.__main__ import reference_from_options

    assert reference_from_options("excitation", 10.0, options,
                                  read_airframe("quad-x-500")).envelope \
        == envelope
    assert reference_from_options("excitation", 10.0, [],
                                  read_airframe("paper")).envelope == PAPER_ENVELOPE
    with pytest.raises(ValueError, match="unknown field 'rate'; known: yaw_rad"):
        reference_from_options("excitation", 10.0, ["rate=1"], read_airframe("quad-x-500"))
