"""The new-vehicle workflow end to end: write an airframe file, identify a model on it
(the SITL excitation flight), fly with it; the model refuses another airframe unless told."""

from __future__ import annotations

import json
from importlib import resources
from pathlib import Path

import pytest

from contracts.airframe_file import read_airframe
from ground.cli.main import main


def test_airframe_file_to_identified_model_to_flight(tmp_path: Path, capsys) -> None:
    text = resources.files("contracts").joinpath("airframes", "realistic.toml").read_text()
    airframe = tmp_path / "my-quad.toml"
    airframe.write_text(text.replace('name = "realistic"', 'name = "my-quad"')
                        .replace("mass_kg = 1.5", "mass_kg = 1.7"))
    model = tmp_path / "model.json"
    assert main(["identify", "--airframe", str(airframe), "--out", str(model)]) == 0
    metadata = json.loads(model.read_text())["metadata"]
    assert metadata["airframe"] == "my-quad"
    assert metadata["airframe_fingerprint"] == read_airframe(str(airframe)).fingerprint()

    run = tmp_path / "run"
    assert main(["run", "attitude-sine", "--inprocess", "--no-figures", "--airframe",
                 str(airframe), "--model", str(model), "--out", str(run)]) == 0
    axes = json.loads((run / "metrics.json").read_text())["axes"]
    # Measured 0.00024 / 0.00048 rad (0.00156 / 0.00095 with the excitation before the
    # envelope, 2000 samples); the paper's target for its own airframe is 0.01.
    assert axes["phi"]["rmse"] == pytest.approx(0.000237, rel=0.05), axes
    assert axes["theta"]["rmse"] == pytest.approx(0.000480, rel=0.05), axes

    # The model on another airframe: refused, saying which, unless asked for.
    capsys.readouterr()
    other = tmp_path / "other"
    assert main(["run", "attitude-sine", "--inprocess", "--no-figures", "--airframe", "paper",
                 "--model", str(model), "--out", str(other)]) == 2
    err = capsys.readouterr().err
    assert "identified on airframe 'my-quad', not on 'paper'" in err
    assert not (other / "metrics.json").exists()
    assert main(["run", "attitude-sine", "--inprocess", "--no-figures", "--airframe", "paper",
                 "--model", str(model), "--any-airframe-model", "--out", str(other)]) == 0


def test_the_same_name_with_other_numbers_is_another_airframe(tmp_path: Path) -> None:
    from autopilot.control.factory import load_models

    text = resources.files("contracts").joinpath("airframes", "paper.toml").read_text()
    heavier = tmp_path / "paper-heavy.toml"
    heavier.write_text(text.replace("mass_kg = 1.2", "mass_kg = 1.3"))  # still named paper
    load_models(None, read_airframe("paper"))  # the shipped model is the paper airframe's
    with pytest.raises(ValueError, match="identified on airframe 'paper' \\(other numbers\\)"):
        load_models(None, read_airframe(str(heavier)))
    assert load_models(None, read_airframe(str(heavier)), any_airframe=True).channels


# Between machines the identification's numbers differ by more than their last bits:
# the clustering and least squares amplify the compiled code's rounding (AVX-512 or not).
# Measured: 1.6e-4 relative at most (theta_f of phi) between an AMD EPYC with AVX-512 and
# the machine that made the shipped model. Any change to the method moves them by more.
MODEL_REL_TOL = 1e-3


def _assert_same_numbers(mine, shipped, where: str = "") -> None:
    """Equal structure and text, numbers to MODEL_REL_TOL."""
    if isinstance(mine, dict):
        assert mine.keys() == shipped.keys(), where
        for key in mine:
            _assert_same_numbers(mine[key], shipped[key], f"{where}.{key}")
    elif isinstance(mine, list):
        assert len(mine) == len(shipped), where
        for i, (a, b) in enumerate(zip(mine, shipped, strict=True)):
            _assert_same_numbers(a, b, f"{where}[{i}]")
    elif isinstance(mine, float):
        assert mine == pytest.approx(shipped, rel=MODEL_REL_TOL, abs=1e-12), where
    else:
        assert mine == shipped, where


def test_the_quad_x_flies_the_papers_tests_with_the_model_the_workflow_identifies(
        tmp_path: Path) -> None:
    """The shipped quad X on the rigid-body plant, with a model identified on it by
    ``ivfm identify``: the issue's targets (x, y <= 0.05 m after 3 s; phi, theta <= 0.02 rad
    after 2 s at the largest amplitude its thrust allows, 0.7 rad), and our numbers (rel
    2 %). The shipped model for it is that same identification, value for value."""
    model = tmp_path / "x500.json"
    assert main(["identify", "--airframe", "quad-x-500", "--out", str(model)]) == 0
    mine, shipped = (json.loads(p.read_text()) for p in (
        model, Path(str(resources.files("autopilot.models").joinpath("quad-x-500.json")))))
    _assert_same_numbers(mine["channels"], shipped["channels"])
    # Position with the airframe file's own CMDF_ACC_MAX (20; at the paper's 8 it was
    # x 0.00489, y 0.00451 and the hover could fall into a limit cycle).
    measured = {"x500-position-sine": {"x": 0.00497, "y": 0.00477},
                "x500-attitude-sine": {"phi": 0.00124, "theta": 0.00126}}
    targets = {"x": 0.05, "y": 0.05, "phi": 0.02, "theta": 0.02}
    for scenario, golden in measured.items():
        run = tmp_path / scenario
        assert main(["run", scenario, "--inprocess", "--no-figures", "--model", str(model),
                     "--out", str(run)]) == 0
        metrics = json.loads((run / "metrics.json").read_text())
        assert metrics["airframe"] == "quad-x-500" and metrics["plant"] == "rigid-body"
        for axis, value in golden.items():
            rmse = metrics["axes"][axis]["rmse"]
            assert rmse <= targets[axis]
            assert rmse == pytest.approx(value, rel=0.02), (scenario, axis, rmse)


def test_an_x_frame_listed_in_another_rotor_order_flies_the_same_closed_loop() -> None:
    """The autopilot and the plant on the quad X in PX4's motor order, and on the same
    vehicle with its rotors listed in another order: the same flight, and each motor's
    command moves with its rotor."""
    import tomllib

    import numpy as np

    from autopilot.control.factory import load_models
    from contracts.airframe import airframe_from_spec
    from contracts.airframe_file import parse_airframe
    from ground.run.inprocess import run_inprocess
    from ground.scenario.scenario_file import scenario_by_name

    data = tomllib.loads(resources.files("contracts").joinpath(
        "airframes", "quad-x-500.toml").read_text())
    order = [2, 0, 3, 1]  # listed rotor j is PX4's motor order[j] + 1
    shuffled = dict(data, rotor=[data["rotor"][m] for m in order])
    models = load_models(None, read_airframe("quad-x-500"))
    scenario = scenario_by_name("x500-position-sine")
    px4, other = (run_inprocess(scenario, "ivfc", "rigid-body",
                                airframe_from_spec(parse_airframe(d)), models)
                  for d in (data, shuffled))
    assert not px4.diverged
    np.testing.assert_allclose(other.measurement, px4.measurement, rtol=0, atol=1e-9)
    np.testing.assert_allclose(other.motor_commands, px4.motor_commands[:, order], rtol=0,
                               atol=1e-9)
    assert np.ptp(px4.motor_commands[200:], axis=0).min() > 0.01  # the motors did work
