"""Where a check's runs fly (``FlightSlots``): a hand-over CPU per place, held for the
whole check, and a lock that one run at a time flies under; how many fly at once."""

from __future__ import annotations

import threading

import pytest

from ground.check.checker import flights_at_once
from ground.cli.check import default_jobs
from ground.run.placement import FlightSlots, HandoverCpus


@pytest.fixture
def four_cpus(monkeypatch):
    monkeypatch.setattr("os.sched_getaffinity", lambda pid: {0, 1, 2, 3})


def test_each_place_holds_a_cpu_for_the_whole_check_and_gives_it_back(tmp_path, four_cpus):
    placed = []
    cpus = HandoverCpus(tmp_path, keep_off=placed.append)
    slots = FlightSlots(2, cpus)
    assert slots.cpus == [3, 2]  # the last CPUs first, as a single run takes them
    assert placed[-1] == {0, 1}  # the command keeps off both while it holds them
    other = HandoverCpus(tmp_path, keep_off=lambda _cpus: None)
    assert other.take() == 1  # another command on the machine gets a CPU of its own
    slots.close()
    assert placed[-1] == {0, 1, 2, 3}
    assert other.take() == 3  # given back


def test_a_run_goes_to_the_place_with_the_fewest_runs(tmp_path, four_cpus):
    slots = FlightSlots(2, HandoverCpus(tmp_path, keep_off=lambda _cpus: None))
    with slots.assign() as a, slots.assign() as b:
        assert (a.cpu, b.cpu) == (3, 2)
        with slots.assign() as c:
            assert c.cpu == 3 and c.lock is a.lock
        with slots.assign() as d:  # c is done: 3 has one run again, as has 2
            assert d.cpu == 3
    with slots.assign() as e:
        assert e.cpu == 3
    slots.close()


def test_one_run_at_a_time_flies_in_a_place(tmp_path, four_cpus):
    slots = FlightSlots(1, HandoverCpus(tmp_path, keep_off=lambda _cpus: None))
    with slots.assign() as first, slots.assign() as second:
        assert first.lock is second.lock
        first.lock.acquire()
        got: list[bool] = []
        waiter = threading.Thread(target=lambda: got.append(second.lock.acquire(timeout=0.05)))
        waiter.start()
        waiter.join()
        assert got == [False]
        first.lock.release()
        assert second.lock.acquire(timeout=1.0)
        second.lock.release()
    slots.close()


def test_on_one_cpu_a_place_has_no_cpu(tmp_path, monkeypatch):
    monkeypatch.setattr("os.sched_getaffinity", lambda pid: {0})
    slots = FlightSlots(1, HandoverCpus(tmp_path, keep_off=lambda _cpus: None))
    assert slots.cpus == [None]  # unplaced, as a single run there
    with slots.assign() as slot:
        assert slot.cpu is None
    slots.close()


@pytest.mark.parametrize(("cpus", "jobs", "flying", "default"), [
    ({0}, 7, 1, 1),
    ({0, 1}, 7, 2, 4),  # two flying, and the next two starting or finishing
    ({0, 1, 2}, 7, 3, 6),
    ({0, 1, 2, 3}, 7, 4, 7),  # never more jobs than scenarios
    ({0, 1, 2, 3}, 1, 1, 7),
    (set(range(8)), 2, 2, 7),
])
def test_one_flight_per_cpu_and_two_runs_in_progress_per_flight(
        monkeypatch, cpus, jobs, flying, default):
    monkeypatch.setattr("os.sched_getaffinity", lambda pid: cpus)
    assert flights_at_once(jobs) == flying
    assert default_jobs(False, 7) == default
    assert default_jobs(True, 7) == 1
    assert default_jobs(False, 1) == 1
