"""The ``ivfm`` command as a user runs it: real processes, real files, bad input refused."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from autopilot.control.factory import load_models


def ivfm(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "ground.cli", *args], capture_output=True,
                          text=True, timeout=300, cwd=cwd)


def test_run_writes_metrics_and_figures(tmp_path: Path) -> None:
    out = tmp_path / "run"
    result = ivfm("run", "attitude-sine", "--inprocess", "--controller", "ivfc",
                  "--plant", "paper", "--out", str(out))
    assert result.returncode == 0, result.stderr
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["scenario"] == "attitude-sine"
    assert metrics["controller"] == "ivfc"
    assert metrics["plant"] == "paper"
    assert metrics["sim_time_s"] == pytest.approx(20.0)
    assert metrics["wall_time_s"] > 0
    assert set(metrics["axes"]) == {"phi", "theta", "psi", "z"}
    assert metrics["axes"]["phi"]["rmse"] <= 0.01
    for name in ("tracking.png", "sliding.png", "adaptive.png", "motors.png"):
        assert (out / name).stat().st_size > 10_000, name
    assert "phi: rmse" in result.stdout


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["run", "no-such-scenario"], "unknown scenario 'no-such-scenario'"),
        (["run", "attitude-sine", "--param", "ATT_LAM=nan"], "ATT_LAM"),
        (["run", "attitude-sine", "--param", "ATT_LAM=inf"], "ATT_LAM"),
        (["run", "attitude-sine", "--param", "NOPE=1"], "unknown parameter 'NOPE'"),
        (["run", "attitude-sine", "--param", "ATT_LAM=-3"], "ATT_LAM"),
        (["run", "attitude-sine", "--controller", "lqr"], "invalid choice: 'lqr'"),
        (["run", "attitude-sine", "--plant", "toy"], "invalid choice: 'toy'"),
    ],
)
def test_bad_arguments_are_refused_and_nothing_is_written(tmp_path: Path, args, message) -> None:
    out = tmp_path / "out"
    result = ivfm(*args, "--out", str(out))
    assert result.returncode == 2
    assert message in result.stderr
    assert not out.exists()


def _write_bad_models(tmp_path: Path) -> dict[str, Path]:
    good = json.loads((Path(load_models.__code__.co_filename).parents[1] / "models"
                       / "paper.json").read_text())
    cases = {}
    cases["not-json"] = "{ this is not json"
    nan = json.loads(json.dumps(good))
    nan["channels"]["phi"]["ivfm"]["theta_f"][0] = "NaN"
    cases["nan"] = json.dumps(nan).replace('"NaN"', "NaN")
    shape = json.loads(json.dumps(good))
    shape["channels"]["theta"]["ivfm"]["lower"] = [[1.0, 0.0]]
    cases["shape"] = json.dumps(shape)
    missing = json.loads(json.dumps(good))
    del missing["channels"]["psi"]
    cases["missing-channel"] = json.dumps(missing)
    paths = {}
    for name, text in cases.items():
        path = tmp_path / f"{name}.json"
        path.write_text(text)
        paths[name] = path
    return paths


def test_malformed_model_files_are_refused(tmp_path: Path) -> None:
    for name, path in _write_bad_models(tmp_path).items():
        out = tmp_path / f"out-{name}"
        result = ivfm("run", "attitude-sine", "--model", str(path), "--out", str(out))
        assert result.returncode == 2, (name, result.stderr)
        assert "ivfm: error:" in result.stderr and str(path) in result.stderr, name
        assert "Traceback" not in result.stderr
        assert not out.exists(), name


def test_identify_prints_table_2_and_writes_a_loadable_model(tmp_path: Path) -> None:
    model = tmp_path / "model.json"
    data = tmp_path / "data.csv"
    result = ivfm("identify", "--samples", "1000", "--out", str(model), "--write-data", str(data))
    assert result.returncode == 0, result.stderr
    assert "paper T1FM" in result.stdout and "1.4016" in result.stdout
    assert "f_psi" in result.stdout and "constant" in result.stdout
    load_models(model)
    # The written data file identifies again from disk (the flight-log path).
    again = tmp_path / "again.json"
    result = ivfm("identify", "--data", str(data), "--out", str(again))
    assert result.returncode == 0, result.stderr
    load_models(again)


def test_identify_refuses_a_malformed_data_file(tmp_path: Path) -> None:
    data = tmp_path / "bad.csv"
    header = ("time_s,phi_rad,theta_rad,psi_rad,phi_rate_rad_s,theta_rate_rad_s,psi_rate_rad_s,"
              "w_r_rad_s,u_phi_n,u_theta_n,u_psi_nm,phi_acc_rad_s2,theta_acc_rad_s2,psi_acc_rad_s2")
    rows = [",".join(["0.0"] * 14).replace("0.0", f"{k * 0.01}", 1) for k in range(50)]
    rows[20] = rows[20].replace(",0.0,", ",nan,", 1)
    data.write_text(header + "\n" + "\n".join(rows) + "\n")
    model = tmp_path / "model.json"
    result = ivfm("identify", "--data", str(data), "--out", str(model))
    assert result.returncode == 2
    assert "not finite" in result.stderr and str(data) in result.stderr
    assert not model.exists()
