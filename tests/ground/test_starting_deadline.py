"""How long a run waits for its processes to start (ground/run/children.py,
``StartingDeadline``): as long as they work, up to a cap; not a fixed minute, which a cold
start beside busy neighbours outlasted (the logger then had not even listened)."""

from __future__ import annotations

import os

import pytest

from ground.run.loader import StartingDeadline, cpu_seconds


class Clock:
    def __init__(self) -> None:
        self.now_s = 100.0

    def __call__(self) -> float:
        return self.now_s


class Cpu:
    """CPU seconds per pid, set by the test."""

    def __init__(self, used: dict[int, float | None]) -> None:
        self.used = used

    def __call__(self, pid: int) -> float | None:
        return self.used[pid]


def test_a_process_that_keeps_working_is_waited_for_past_the_idle_limit():
    clock, cpu = Clock(), Cpu({1: 0.5, 2: 0.4})
    wait = StartingDeadline({"logger": 1, "simulator": 2}, idle_s=60.0, clock=clock, cpu=cpu)
    for _ in range(20):  # 200 s, the simulator compiling all along
        clock.now_s += 10.0
        cpu.used[2] += 2.0
        assert wait.expired("x") is None


def test_no_cpu_for_the_idle_limit_ends_the_wait_saying_so():
    clock, cpu = Clock(), Cpu({1: 0.5})
    wait = StartingDeadline({"logger": 1}, idle_s=60.0, clock=clock, cpu=cpu)
    clock.now_s += 30.0
    cpu.used[1] = 0.7
    assert wait.expired("x") is None
    clock.now_s += 60.0  # 60 s since it last used CPU: not yet over
    assert wait.expired("x") is None
    clock.now_s += 0.5
    assert wait.expired("x") == ("after 90 s: no process of the run used any CPU for 60 s")


def test_the_cap_ends_even_a_busy_wait():
    clock, cpu = Clock(), Cpu({1: 0.0})
    wait = StartingDeadline({"logger": 1}, idle_s=60.0, cap_s=300.0, clock=clock, cpu=cpu)
    while (why := wait.expired("x")) is None:
        clock.now_s += 10.0
        cpu.used[1] += 5.0
        assert clock.now_s - 100.0 <= 310.0
    assert why == "after 310 s (the longest a start may take)"


def test_a_gone_process_is_no_progress_and_the_wait_says_what_it_waits_for():
    clock, cpu, said = Clock(), Cpu({1: 1.0, 2: 2.0}), []
    wait = StartingDeadline({"logger": 1, "autopilot": 2}, idle_s=20.0, say=said.append,
                            note_every_s=15.0, clock=clock, cpu=cpu)
    cpu.used[2] = None  # the autopilot's pid is gone
    clock.now_s += 16.0
    assert wait.expired("the logger to hear a, b") is None
    assert said == ["still waiting for the logger to hear a, b (16 s; CPU used so far: "
                    "the logger 1.0 s; a first run after a change compiles for a while)"]
    clock.now_s += 5.0
    assert wait.expired("the logger to hear a, b") is not None


def test_cpu_seconds_reads_this_process_and_none_for_no_process():
    before = cpu_seconds(os.getpid())
    assert before is not None and before > 0.0
    end = before + 0.05
    while (cpu_seconds(os.getpid()) or 0.0) < end:
        sum(range(10_000))
    assert cpu_seconds(os.getpid()) == pytest.approx(end, abs=0.05)
    assert cpu_seconds(2**22 + 12345) is None  # above the kernel's pid limit
