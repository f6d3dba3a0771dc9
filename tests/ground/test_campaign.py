"""Campaigns (ground/campaign): files, seeded draws, the draw's scenario, the statistics and
the report, in process; the Dask runs, the resume and a killed worker in the process
tier."""

from __future__ import annotations

import json
import math
import os
import signal
import tomllib

import numpy as np
import pytest

from ground.campaign.report import flight_report, identification_report, markdown
from ground.campaign.run import (
    draw_scenario,
    flight_tasks,
    identification_tasks,
    read_rows,
    run_campaign,
    run_task,
)
from ground.campaign.spec import parse_campaign, read_campaign, shipped_campaigns
from ground.campaign.stats import paired, summary, verdict
from ground.scenario.scenario_file import load_scenario

BASE = {"name": "t", "scenarios": ["attitude-jr-20"], "controllers": ["ivfc", "t1fc"],
        "runs": 4, "seed": 3,
        "draw": {"mass_scale": {"uniform": [0.9, 1.1]}, "jr_scale": {"normal": [1.0, 0.1]},
                 "motor_efficiency": {"uniform": [0.9, 1.0]},
                 "sensor_seed": {"integers": [0, 9]}}}


def test_the_shipped_campaigns_read():
    assert set(shipped_campaigns()) >= {"smoke", "paper-comparison", "paper-identification"}
    for name in shipped_campaigns():
        assert read_campaign(name).tasks > 0
    assert read_campaign("paper-comparison").runs >= 200
    identification = read_campaign("paper-identification")
    assert identification.runs >= 50 and len(identification.clusters) >= 3


def test_a_draw_depends_on_the_seed_and_its_index_alone():
    campaign = parse_campaign(BASE)
    more = parse_campaign({**BASE, "runs": 400})
    assert campaign.draw(2) == more.draw(2)  # adding runs keeps the draws
    assert campaign.draw(2) != campaign.draw(3)
    assert parse_campaign({**BASE, "seed": 4}).draw(2) != campaign.draw(2)
    values = campaign.draw(0)
    assert set(values) == {"mass_scale", "jr_scale", "sensor_seed",
                           *(f"motor_efficiency_{m}" for m in range(1, 5))}
    draws = [more.draw(i) for i in range(400)]
    masses = [d["mass_scale"] for d in draws]
    assert 0.9 <= min(masses) < 0.91 and 1.09 < max(masses) <= 1.1
    assert np.std([d["jr_scale"] for d in draws]) == pytest.approx(0.1, rel=0.15)
    assert {d["sensor_seed"] for d in draws} == set(range(10))


@pytest.mark.parametrize("change, error", [
    ({"runs": 0}, "runs must be a whole number"),
    ({"runs": 1.5}, "runs must be a whole number"),
    ({"controllers": ["ivfc", "lqr"]}, "unknown lqr"),
    ({"scenarios": ["nowhere"]}, "nowhere"),
    ({"draw": {"mass_scale": {"uniform": [0.1, 1.0]}}}, "out of"),
    ({"draw": {"mass_scale": {"uniform": [1.1, 0.9]}}}, "above high"),
    ({"draw": {"mass_scale": {"uniform": [0.9, math.nan]}}}, "finite"),
    ({"draw": {"weight": {"value": 1}}}, "unknown factor"),
    ({"draw": {"sensor_seed": {"uniform": [0, 5]}}}, "whole number"),
    ({"draw": {"mass_scale": {"poisson": [1]}}}, "unknown distribution"),
    ({"how": "cloud"}, "how must be"),
    ({"speed": 3}, "unknown field"),
    ({"clusters": [4]}, "for identification campaigns"),
])
def test_a_bad_campaign_is_refused_naming_the_field(change, error):
    with pytest.raises(ValueError, match=error):
        parse_campaign({**BASE, **change})


def test_the_draws_scenario_is_the_base_with_the_drawn_plant(tmp_path):
    campaign = parse_campaign({**BASE, "draw": {
        "mass_scale": {"value": 1.05}, "wind_mps": {"value": 2.0},
        "perturbation_scale": {"value": 0.5}, "identification_seed": {"value": 7}}})
    name, text = draw_scenario(campaign, "attitude-jr-20", 3, campaign.draw(3),
                               "paper-seed7-c5.json")
    assert name == "attitude-jr-20-d00003.toml"
    data = tomllib.loads(text)
    assert "expect" not in data and data["controller"]["model"] == \
        "../models/paper-seed7-c5.json"
    kinds = [(p["kind"], p.get("scale"), p["start_s"], p["end_s"]) for p in data["perturbation"]]
    # The scenario's 20 % steps halved, the mass over the whole run, the wind too.
    assert kinds[:3] == [("inertia", pytest.approx(1.1), 12.0, 14.0),
                         ("rotor_inertia", pytest.approx(1.1), 12.0, 14.0),
                         ("mass", 1.05, 0.0, 20.0)]
    wind = data["perturbation"][3]["ned_mps"]
    assert math.hypot(*wind) == pytest.approx(2.0) and wind[2] == 0.0
    (tmp_path / "draws").mkdir()
    (tmp_path / "draws" / name).write_text(text)
    scenario = load_scenario(tmp_path / "draws" / name)  # a scenario file ivfm run takes
    assert scenario.model_path == tmp_path / "draws" / "../models/paper-seed7-c5.json"
    assert len(scenario.perturbations) == 4


def test_tasks_pair_every_controller_on_every_draw():
    campaign = parse_campaign(BASE)
    tasks = flight_tasks(campaign)
    assert len(tasks) == campaign.tasks == 8
    assert [t["id"] for t in tasks[:2]] == ["attitude-jr-20-d00000-ivfc",
                                            "attitude-jr-20-d00000-t1fc"]
    assert tasks[0]["draw_toml"] == tasks[1]["draw_toml"]
    grid = identification_tasks(parse_campaign({"kind": "identification", "runs": 3,
                                                "seed": 10, "clusters": [3, 5]}))
    assert [t["id"] for t in grid] == ["s000010-c3", "s000010-c5", "s000011-c3",
                                       "s000011-c5", "s000012-c3", "s000012-c5"]


def test_a_failing_run_is_a_row_with_its_reason():
    task = flight_tasks(parse_campaign(BASE))[0]
    task["draw_toml"] = task["draw_toml"].replace("attitude-sine", "no-such-reference")
    row = run_task(task)
    assert row["id"] == task["id"] and "no-such-reference" in row["error"]
    assert row["mass_scale"] == task["values"]["mass_scale"]


def test_a_flight_task_flies_the_draw_as_ivfm_run_would():
    from ground.run.flights import Overrides, fly_inprocess, plan_flight

    task = flight_tasks(parse_campaign({**BASE, "draw": {"mass_scale": {"value": 1.1}}}))[0]
    row = run_task(task)
    assert not row["error"] and not row["diverged"]
    # The replay command's flight: the same numbers.
    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory() as tmp:
        draw = Path(tmp) / task["draw_file"]
        draw.write_text(task["draw_toml"])
        metrics = fly_inprocess(plan_flight(load_scenario(draw),
                                            Overrides(controller="ivfc")), Path(tmp),
                                figures=False)
    assert row["phi_rmse"] == metrics["axes"]["phi"]["rmse"]
    assert row["replay"] == f"ivfm run draws/{task['draw_file']} --controller ivfc --seed 0 " \
                            "--inprocess"


def test_statistics_on_known_data():
    rng = np.random.default_rng(0)
    a = rng.lognormal(0.0, 0.3, 300)
    s = summary(a)
    assert s["n"] == 300 and s["mean_ci"][0] < s["mean"] < s["mean_ci"][1]
    assert s["median_ci"][0] < 1.0 < s["median_ci"][1]  # the true median is 1
    better = paired(a * 0.9, a)
    assert better["wins"] == 300 and better["win_rate_ci"][0] > 0.98
    assert better["median_ratio"] == pytest.approx(0.9)
    assert verdict(better) == "a better"
    same = paired(a, a[::-1])
    assert verdict(same) == "no clear difference"
    assert paired([np.nan, 1.0], [1.0, np.nan])["n"] == 0


def test_the_report_compares_controllers_draw_by_draw():
    rows = []
    for draw in range(40):
        for controller, scale in (("ivfc", 1.0), ("t1fc", 1.5)):
            rows.append({"id": f"s-d{draw}-{controller}", "scenario": "s", "draw": draw,
                         "controller": controller, "mass_scale": 1 + draw / 100,
                         "phi_rmse": scale * (1 + draw / 40), "theta_rmse": 1.0 + draw % 2,
                         "error": ""})
    rows.append({"id": "s-d40-ivfc", "scenario": "s", "draw": 40, "controller": "ivfc",
                 "phi_rmse": None, "error": "diverged: the vehicle left the flight envelope"})
    report = flight_report(rows, ("ivfc", "t1fc"))
    section = report["scenarios"]["s"]
    assert section["controllers"]["ivfc"]["failed"] == 1
    phi = section["paired"]["ivfc vs t1fc"]["phi"]
    assert phi["n"] == 40 and phi["wins"] == 40 and phi["verdict"] == "ivfc better"
    assert section["paired"]["ivfc vs t1fc"]["theta"]["verdict"] == "no clear difference"
    text = markdown("c", "flights", report)
    assert "| phi | 40/40 " in text and "diverged" in text
    ident = identification_report([
        {"id": f"s{i}", "clusters": 4, "phi_ivfm_rmse": 0.1, "phi_t1fm_rmse": 0.2,
         "theta_ivfm_rmse": 0.3, "theta_t1fm_rmse": 0.2, "psi_ivfm_rmse": 0.1 + i / 100,
         "psi_t1fm_rmse": 0.1 + (9 - i) / 100, "error": ""} for i in range(10)])
    verdicts = {ch: ident["clusters"]["4"][ch]["paired"]["verdict"]
                for ch in ("phi", "theta", "psi")}
    assert verdicts == {"phi": "IVFM better", "theta": "T1FM better",
                        "psi": "no clear difference"}


@pytest.mark.process
def test_a_campaign_on_a_local_cluster_survives_a_killed_worker_and_resumes(tmp_path):
    """Two Dask workers fly 6 draws x 2 controllers; one worker is killed after the first
    result (its runs are redone); a rerun flies nothing; more runs fly only the new."""
    campaign = parse_campaign({**BASE, "runs": 6})
    killed: list[int] = []

    def kill_one(row, client):
        if not killed:
            pids = list(client.run(os.getpid).values())
            victim = next(p for p in pids if p != row["worker_pid"]) if len(pids) > 1 \
                else pids[0]
            os.kill(victim, signal.SIGKILL)
            killed.append(victim)

    counts = run_campaign(campaign, tmp_path, workers=2, on_result=kill_one)
    assert killed and counts == {"total": 12, "skipped": 0, "flown": 12, "failed": 0}
    rows = read_rows(tmp_path)
    assert len(rows) == 12 and not any(r["error"] for r in rows)
    assert len({r["worker_pid"] for r in rows}) >= 2
    assert (tmp_path / "results.csv").read_text().count("\n") == 13
    again = run_campaign(campaign, tmp_path, workers=1)
    assert again == {"total": 12, "skipped": 12, "flown": 0, "failed": 0}
    more = run_campaign(parse_campaign({**BASE, "runs": 7}), tmp_path, workers=1)
    assert more == {"total": 14, "skipped": 12, "flown": 2, "failed": 0}
    first = {r["id"]: r["phi_rmse"] for r in rows}
    assert {r["id"]: r["phi_rmse"] for r in read_rows(tmp_path) if r["id"] in first} == first
    assert json.loads((tmp_path / "runs" / "attitude-jr-20-d00006-t1fc.json").read_text())[
        "draw"] == 6


@pytest.mark.process
def test_ctrl_c_keeps_every_finished_run_and_the_rerun_flies_only_the_rest(tmp_path):
    import subprocess
    import sys
    import time

    out = tmp_path / "smoke"
    argv = [sys.executable, "-m", "ground.cli", "campaign", "smoke", "--runs", "20", "--out",
            str(out), "--workers", "2"]
    # Ctrl-C as a terminal sends it (SIGINT handled: a shell's background job has it
    # ignored, and the child would inherit that).
    first = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                             preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    deadline = time.monotonic() + 120
    while len(list((out / "runs").glob("*.json"))) < 6 and time.monotonic() < deadline:
        time.sleep(0.05)
    first.send_signal(signal.SIGINT)
    _, err = first.communicate(timeout=60)
    assert first.returncode == 130, err
    assert "finished runs are in" in err
    kept = {p.stem for p in (out / "runs").glob("*.json")}
    assert 6 <= len(kept) < 40
    # The count said is the runs on disk, with those the workers finished after Ctrl-C.
    assert f"stopped: {len(kept)} runs finished this time are kept" in err
    again = subprocess.run(argv, capture_output=True, text=True, timeout=300)
    assert again.returncode == 0, again.stderr
    assert f"{40 - len(kept)} runs flown (0 failed), {len(kept)} done before, of 40" in \
        again.stderr
    assert len(read_rows(out)) == 40
