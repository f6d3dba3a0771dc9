"""Scenarios through every process: logger + simulator + autopilot, perturbations over
Zenoh, metrics from the MCAP log (lockstep and real time)."""

from __future__ import annotations

import dataclasses
import os
import re
import threading
import time

import numpy as np
import pytest

from contracts.airframe import PAPER
from ground.record.run_files import control_records, perturbation_events
from ground.report.metrics import compute_metrics
from ground.run.inprocess import run_inprocess
from ground.run.processes import RunSettings, fly
from ground.scenario.scenario_file import scenario_by_name

pytestmark = pytest.mark.process

IVFC = RunSettings("ivfc", "paper", "paper")


@pytest.mark.parametrize("name", ["attitude-jr-10", "attitude-jr-15", "attitude-jr-20",
                                  "position-kick"])
def test_perturbation_scenarios_over_zenoh_match_in_process(name, shipped_models, tmp_path):
    scenario = scenario_by_name(name)
    ours, accounting = fly(scenario, IVFC, tmp_path)
    reference = run_inprocess(scenario, "ivfc", "paper", PAPER, shipped_models)
    # Zero loss: every record each process says it published is in the log.
    assert accounting["lost"] == {}
    assert accounting["published"]["ivfm/vehicle/1/autopilot/control"] == 2000
    assert not ours.diverged
    np.testing.assert_array_equal(ours.time_s, reference.time_s)
    # The autopilot reads float32 ODOMETRY; the state stays within float32-level noise.
    assert np.max(np.abs(ours.measurement - reference.measurement)) < 1e-4
    a = compute_metrics(ours, scenario, "paper")["axes"]
    b = compute_metrics(reference, scenario, "paper")["axes"]
    for axis in scenario.axes:
        assert a[axis]["rmse"] == pytest.approx(b[axis]["rmse"], rel=1e-3, abs=1e-6), axis
    # Each perturbation was applied, and logged, at the sim time its window says.
    events = perturbation_events(tmp_path, 1)
    expected = sorted((round(t * 1e6), ev, e.id) for e in scenario.perturbations
                      for t, ev in ((e.start_s, "start"), (e.end_s, "end")))
    assert sorted((e["sim_time_us"], e["event"], e["id"]) for e in events) == expected
    targets = {e["process"] for e in events}
    assert targets == {"autopilot" if name == "position-kick" else "sitl"}


def test_two_lockstep_runs_log_identical_records(tmp_path):
    scenario = dataclasses.replace(scenario_by_name("attitude-jr-10"), duration_s=14.0)
    fly(scenario, IVFC, tmp_path / "a")
    fly(scenario, IVFC, tmp_path / "b")
    first, second = control_records(tmp_path / "a", 1), control_records(tmp_path / "b", 1)
    assert len(first["seq"]) == 1400 and first["missing_count"] == 0
    for field, values in first.items():
        if field != "log_time_ns":  # the wall clock of arrival
            np.testing.assert_array_equal(values, second[field], err_msg=field)


def test_hil_state_source_flies_the_scenario(tmp_path):
    """HIL_STATE_QUATERNION alone (cm, mm, 1e-7 deg) still tracks position-sine."""
    scenario = dataclasses.replace(scenario_by_name("position-sine"), duration_s=10.0)
    record, _ = fly(scenario, dataclasses.replace(IVFC, state_source="hil-state"), tmp_path)
    metrics = compute_metrics(record, scenario, "paper")
    assert not record.diverged
    assert metrics["axes"]["x"]["rmse"] < 0.05 and metrics["axes"]["y"]["rmse"] < 0.05


def test_the_command_keeps_its_threads_off_its_lockstep_runs_handover_cpu(tmp_path):
    """The command's own threads (here this test's, one of them sampling) leave the CPU
    its run's two loops hand over on while the run flies, and come back after: a wake-up
    of the command there preempted a loop. A run left unplaced (every CPU taken by other
    runs) moves nothing."""
    every = frozenset(os.sched_getaffinity(0))
    seen: set[frozenset[int]] = set()
    done = threading.Event()

    def sample() -> None:  # there before the run: placed with the command's other threads
        while not done.is_set():
            seen.add(frozenset(os.sched_getaffinity(0)))
            time.sleep(0.002)

    sampler = threading.Thread(target=sample)
    sampler.start()
    try:
        fly(dataclasses.replace(scenario_by_name("attitude-hold"), duration_s=3.0), IVFC,
            tmp_path)
    finally:
        done.set()
        sampler.join()
    assert frozenset(os.sched_getaffinity(0)) == every  # back where it was
    said = re.search(r"threads kept off CPU (\d+)", (tmp_path / "sitl.log").read_text())
    if said is None:  # unplaced
        assert seen == {every}
    else:
        assert seen == {every, every - {int(said[1])}}


@pytest.mark.alone  # the loop's period, and nothing lost
def test_real_time_run_reports_loop_timing(tmp_path):
    scenario = dataclasses.replace(scenario_by_name("attitude-sine"), duration_s=4.0)
    record, accounting = fly(scenario, dataclasses.replace(IVFC, realtime=True), tmp_path)
    timing = accounting["timing"]
    assert not record.diverged
    assert accounting["lost"] == {}
    assert timing["steps"] == 400
    for key in ("jitter_p50_ms", "jitter_p99_ms", "jitter_max_ms", "compute_p99_ms",
                "deadline_misses"):
        assert key in timing
    assert timing["period_mean_ms"] == pytest.approx(10.0, rel=0.05)
    # The log's per-step timing records agree with the summary's step count.
    assert accounting["published"]["ivfm/vehicle/1/autopilot/timing"] == 400
    # Tracking in real time is close to lockstep (the autopilot sees samples up to one
    # period old), not identical.
    metrics = compute_metrics(record, scenario, "paper")
    assert metrics["axes"]["phi"]["rmse"] < 0.01 and metrics["axes"]["theta"]["rmse"] < 0.01


def test_lockstep_runs_in_flight_share_out_the_cpus_for_their_hand_overs(monkeypatch,
                                                                           tmp_path):
    """Each lockstep run's two loops share one CPU; runs in flight together on the machine
    (ivfm check -j 2, a campaign's worker processes) take different ones, the last CPU
    first, through lock files; with every CPU taken, or one CPU only, a run is unplaced.
    A lock held by another process counts: it goes only with that process."""
    import subprocess
    import sys

    from ground.run.placement import HandoverCpus

    monkeypatch.setattr("os.sched_getaffinity", lambda pid: {0, 1})
    placed_here, placed_other = [], []  # where each process keeps its own threads
    here = HandoverCpus(tmp_path, keep_off=placed_here.append)
    other = HandoverCpus(tmp_path, keep_off=placed_other.append)
    first, second = here.take(), other.take()
    assert (first, second) == (1, 0)
    assert (placed_here, placed_other) == ([{0}], [{1}])  # each off its runs' CPU
    assert here.take() is None  # both taken: unplaced
    assert placed_here == [{0}]
    here.give(first)
    assert placed_here == [{0}, {0, 1}]  # back on every CPU it had
    assert here.take() == 1  # the one given back
    here.give(1)
    other.give(0)
    assert placed_other == [{1}, {0, 1}]
    both = HandoverCpus(tmp_path, keep_off=placed_here.append)
    assert (both.take(), both.take()) == (1, 0)  # ivfm check -j 2: one process, two runs
    assert placed_here[-2:] == [{0}, {0, 1}]  # off neither when it holds every CPU
    both.give(1)
    assert placed_here[-1] == {1}
    both.give(0)
    holder = subprocess.Popen(  # another process holds CPU 1's lock
        [sys.executable, "-c", "import fcntl, os, sys, time; "
         f"fd = os.open({str(tmp_path / 'ivfm-handover-cpu1.lock')!r}, "
         "os.O_CREAT | os.O_RDWR); fcntl.flock(fd, fcntl.LOCK_EX); print(1, flush=True); "
         "time.sleep(60)"], stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "1"
        assert here.take() == 0
        here.give(0)
    finally:
        holder.kill()
        holder.wait()
    assert here.take() == 1  # gone with its process
    monkeypatch.setattr("os.sched_getaffinity", lambda pid: {3})
    assert HandoverCpus(tmp_path).take() is None
