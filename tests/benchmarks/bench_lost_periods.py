"""What lost control periods cost an orbit, in process, each part apart: the figures of
docs/mavlink.md (Time, "What a stop cost before").

    python tests/benchmarks/bench_lost_periods.py

A 4 m orbit at 1.5 m/s facing the centre (tests/flight.py, the real-time sample pattern:
every sample taken as it arrives, the step taking the newest again), 20 s onto the
circle, then n control periods lost while the plant flies on. Printed per n: the largest
speed error in the 3 s after, for

* ``now``: as the autopilot does it;
* ``a period per step``: the setpoints moved on by one period at the step after the
  loss, as when each sample was counted twice in real time (they fall behind for good);
* ``one long step``: the lost periods shaped in one step instead of one by one;
* ``50 ms cap``: the setpoints' step capped at 50 ms (MAX_SETPOINT_STEP_S before);
* ``held only``: no period lost to the controller (a step on every sample) but its
  command held by the plant: what holding the command costs;
* ``controller fed dt``: the first step's controller run with the periods lost as its
  period (its integrators and command filter advance by them).

Asserts nothing.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parents[2]))

import autopilot.flight_tasks.task as task  # noqa: E402
from contracts.modes import FlightMode  # noqa: E402
from tests.flight import Flight  # noqa: E402

LOST = (0, 1, 2, 3, 4, 5, 6, 9, 19)


def _orbit() -> Flight:
    f = Flight()
    f.take_off(3.0)
    f.vehicle.tasks[FlightMode.ORBIT].request(np.array([6.0, 0.0, math.nan]), 4.0, 1.5, 0)
    f.vehicle.set_mode(FlightMode.ORBIT, f.t_s)
    f.run(20.0, samples_arrive=True)
    return f


def _loss_mm_s(f: Flight, since_s: float) -> float:
    f.run(3.0, samples_arrive=True)
    speed = np.hypot(*f.since(since_s)[:, 4:6].T)
    return 1e3 * float(np.abs(speed - 1.5).max())


def now(f: Flight, n: int) -> None:
    f.lose(n, samples_arrive=True)
    f.run(0.01, samples_arrive=True)


def one_long_step(f: Flight, n: int) -> None:
    state = f.vehicle.state
    begin = state.begin_step

    def begin_once() -> None:
        begin()
        state.step_periods = 1
        state.begin_step = begin  # the next steps as usual
    state.begin_step = begin_once
    now(f, n)


def a_period_per_step(f: Flight, n: int) -> None:
    state = f.vehicle.state
    begin = state.begin_step

    def begin_once() -> None:
        begin()
        state.step_s, state.step_periods = state.period_s, 1
        state.begin_step = begin
    state.begin_step = begin_once
    now(f, n)


def held_only(f: Flight, n: int) -> None:
    for _ in range(n):
        f.vehicle.step(f.t_s, f.plant.true_measurement())  # not applied
        f.plant.advance(f.period_s)
        f.steps += 1
    f.run(0.01, samples_arrive=True)


def controller_fed_dt(f: Flight, n: int) -> None:
    controller = f.vehicle.flight.controller
    f.lose(n, samples_arrive=True)
    controller.period_s = f.period_s * (n + 1)
    f.run(0.01, samples_arrive=True)
    controller.period_s = f.period_s


def main() -> None:
    ways: dict[str, Callable[[Flight, int], None]] = {
        "now": now, "a period per step": a_period_per_step,
        "one long step": one_long_step, "50 ms cap": now,
        "held only": held_only, "controller fed dt": controller_fed_dt}
    print("speed error [mm/s] in the 3 s after n lost periods (n + 1 between two steps)")
    print(f"{'':20s}" + "".join(f"{f'n={n}':>9s}" for n in LOST))
    for name, way in ways.items():
        cap = task.MAX_SETPOINT_STEP_S
        task.MAX_SETPOINT_STEP_S = 0.05 if name == "50 ms cap" else cap
        row = []
        for n in LOST:
            f = _orbit()
            since = f.t_s
            way(f, n)
            row.append(_loss_mm_s(f, since))
        task.MAX_SETPOINT_STEP_S = cap
        print(f"{name:20s}" + "".join(f"{x:9.2f}" for x in row), flush=True)


if __name__ == "__main__":
    main()
