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


@pytest.mark.process
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


@pytest.mark.process
@pytest.mark.parametrize("command", [["run"], ["check", "--cold"]],
                         ids=["forked by the loader", "started by the command"])
def test_a_run_whose_command_is_killed_leaves_no_process_behind(tmp_path: Path,
                                                                 command: list[str]) -> None:
    """SIGTERM to ``ivfm run`` or ``ivfm check`` (a CI job's timeout, a user's kill)
    mid-flight: the run's logger, simulator and autopilot end too, the logger with its
    file finished, instead of flying on and logging for good (they did, up to this
    test). Forked processes are stopped by the process loader; those the command starts
    itself (``--cold``) by the parent-death signal."""
    import os
    import signal
    import time

    scenario = tmp_path / "long.toml"
    shipped = Path(__file__).parents[2] / "ground" / "scenario" / "shipped"
    text = (shipped / "attitude-sine.toml").read_text()
    assert "duration_s = 20.0" in text
    scenario.write_text(text.replace("duration_s = 20.0", "duration_s = 600.0"))
    out = tmp_path / "out"
    ivfm_run = subprocess.Popen([sys.executable, "-m", "ground.cli", *command, str(scenario),
                                 "--out", str(out)],
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 60.0
        while not any("autopilot connected" in _text(log) for log in out.glob("**/sitl.log")):
            assert ivfm_run.poll() is None and time.monotonic() < deadline
            time.sleep(0.05)
        assert len(_writing_into(out)) == 3  # the logger, the simulator, the autopilot
        ivfm_run.send_signal(signal.SIGTERM)
        ivfm_run.wait(timeout=30)
    finally:
        if ivfm_run.poll() is None:
            ivfm_run.kill()
    deadline = time.monotonic() + 10.0
    while _writing_into(out) and time.monotonic() < deadline:
        time.sleep(0.05)
    left = _writing_into(out)
    for pid in left:
        os.kill(pid, signal.SIGKILL)
    assert not left
    assert list(out.glob("**/telemetry-*.mcap")) and not list(out.glob("**/*.active"))


def _text(path: Path) -> str:
    return path.read_text(errors="replace") if path.exists() else ""


def _writing_into(folder: Path) -> list[int]:
    """Processes whose standard output is a file in ``folder`` (a run's logs)."""
    import os

    pids = []
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                if os.readlink(f"/proc/{entry}/fd/1").startswith(f"{folder}/"):
                    pids.append(int(entry))
            except OSError:
                continue
    return pids


@pytest.mark.process
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


@pytest.mark.process
def test_malformed_model_files_are_refused(tmp_path: Path) -> None:
    for name, path in _write_bad_models(tmp_path).items():
        out = tmp_path / f"out-{name}"
        result = ivfm("run", "attitude-sine", "--model", str(path), "--out", str(out))
        assert result.returncode == 2, (name, result.stderr)
        assert "ivfm: error:" in result.stderr and str(path) in result.stderr, name
        assert "Traceback" not in result.stderr
        assert not out.exists(), name


# Our Table 2 (validation RMSE, (T1FM, IVFM)) for `ivfm identify`: the excitation flown
# with seed 0 (4000 samples, 5 % output noise, 2000 + 2000 split), GK seed 0,
# DEFAULT_N_CLUSTERS = 5: the shipped paper.json. Deterministic; produced by the commit
# that designed the excitation for an envelope (regenerate:
# identify_dataset(excitation_dataset(PAPER, seed=0), seed=0)).
# f_psi = (Ixx - Iyy) / Izz phi' theta' is identically 0 on the paper airframe (Ixx = Iyy)
# and its noise is 5 % of that amplitude, so both models reproduce 0 exactly.
# Noise floor of the validation RMSE (noise std, 5 % of max |f|): 0.092 f_phi, 0.053 f_theta.
OUR_TABLE_2 = {"phi": (0.121774, 0.119382), "theta": (0.091780, 0.084288), "psi": (0.0, 0.0)}
# 2 %: the pipeline is deterministic (seeded excitation, noise and GK), so only last-bit
# float differences of another CPU or BLAS enter, through clustering and least squares.
TABLE_2_REL = 0.02


def _table_rows(stdout: str) -> dict[str, list[str]]:
    """{channel: [paper T1FM, paper IVFM, our T1FM, our IVFM, verdict]} of the printed table."""
    rows = {}
    for line in stdout.splitlines():
        fields = line.split()
        if fields and fields[0] in ("f_phi", "f_theta", "f_psi"):
            rows[fields[0][2:]] = fields[1:]
    return rows


def test_identification_reproduces_our_table_2_in_process() -> None:
    """The identification the CLI runs, called directly: our validation RMSEs per channel
    (golden), IVFM better than T1FM where there is something to model (the paper's
    claim), and the input gains g close to the airframe's b1, b2, b3."""
    from autopilot.identification.identify import DEFAULT_N_CLUSTERS, identify_dataset
    from contracts.airframe import PAPER, attitude_coefficients
    from ground.identify.excitation import excitation_dataset

    dataset = excitation_dataset(PAPER, seed=0)
    models = identify_dataset(dataset, n_clusters=DEFAULT_N_CLUSTERS, seed=0)
    assert list(models.channels) == ["phi", "theta", "psi"]
    for name, (t1fm, ivfm) in OUR_TABLE_2.items():
        ch = models.channels[name]
        assert ch.output == "f" and ch.n_clusters == DEFAULT_N_CLUSTERS
        got = (ch.rmse_valid_t1fm, ch.rmse_valid_ivfm)
        assert got == pytest.approx((t1fm, ivfm), rel=TABLE_2_REL, abs=1e-12), (name, got)
    # The paper's ordering; by 2 % on phi and 8 % on theta with this seed (over 50 seeds
    # IVFM wins most identifications: docs/reproducing.md).
    for name in ("phi", "theta"):
        ch = models.channels[name]
        assert ch.rmse_valid_ivfm < ch.rmse_valid_t1fm, name
    assert models.channels["psi"].notes and "constant (0)" in models.channels["psi"].notes[0]
    # g is estimated from the noisy accelerations by least squares: within 1 % of the truth.
    coeffs = attitude_coefficients(PAPER)
    for name, b in (("phi", coeffs.b1), ("theta", coeffs.b2), ("psi", coeffs.b3)):
        ch = models.channels[name]
        assert ch.ivfm.g == pytest.approx(b, rel=0.01), name
        assert ch.t1fm.g == pytest.approx(b, rel=0.01), name


@pytest.mark.process
def test_identify_prints_table_2_and_writes_a_loadable_model(tmp_path: Path) -> None:
    model = tmp_path / "model.json"
    data = tmp_path / "data.csv"
    # 10 s of excitation do not cover the envelope: refused, the data written, no model.
    refused = ivfm("identify", "--samples", "1000", "--out", str(model), "--write-data",
                   str(data))
    assert refused.returncode == 2
    assert "does not cover the envelope" in refused.stderr and "--allow-narrow" in refused.stderr
    assert "phi_rad                1.000" in refused.stdout and "no (62 %)" in refused.stdout
    assert data.exists() and not model.exists()
    narrow = ivfm("identify", "--samples", "1000", "--allow-narrow", "--out", str(model))
    assert narrow.returncode == 0, narrow.stderr
    assert "warning: the data does not cover the envelope" in narrow.stderr
    assert not load_models(model).metadata["covered"]
    result = ivfm("identify", "--out", str(model), "--write-data", str(data))
    assert result.returncode == 0, result.stderr
    assert load_models(model).metadata["covered"]
    assert "paper T1FM" in result.stdout and "our IVFM" in result.stdout
    rows = _table_rows(result.stdout)
    assert set(rows) == set(OUR_TABLE_2)
    written = load_models(model)
    for name, (t1fm, ivfm_rmse) in OUR_TABLE_2.items():
        _paper_t1, _paper_iv, our_t1, our_iv, verdict = rows[name]
        # The printed numbers are ours (golden) and are the ones the model file holds.
        assert (float(our_t1), float(our_iv)) == pytest.approx((t1fm, ivfm_rmse),
                                                               rel=TABLE_2_REL, abs=1e-4), name
        ch = written.channels[name]
        assert (our_t1, our_iv) == (f"{ch.rmse_valid_t1fm:.4f}", f"{ch.rmse_valid_ivfm:.4f}")
        assert verdict == ("equal" if name == "psi" else "yes"), name
    assert "f_psi" in result.stdout and "constant" in result.stdout
    # The written data file identifies again from disk (the flight-log path): the CSV
    # round trip is exact, so the table is the same to the last printed digit.
    again = tmp_path / "again.json"
    result_again = ivfm("identify", "--data", str(data), "--out", str(again))
    assert result_again.returncode == 0, result_again.stderr
    assert _table_rows(result_again.stdout) == rows
    load_models(again)


@pytest.mark.process
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
