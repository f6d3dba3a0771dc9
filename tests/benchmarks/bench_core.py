"""Benchmarks of the numerical core; prints the figures.

Run: python tests/benchmarks/bench_core.py

Not a test: timings depend on the machine. Each figure is the median of several repeats
after a warm-up (numba compiles on first call).
"""

from __future__ import annotations

import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

from autopilot.control.factory import (
    load_models,  # noqa: E402
    make_controller,  # noqa: E402
)
from autopilot.flight_tasks.shaper import SetpointShaper  # noqa: E402
from autopilot.flight_tasks.shaping import (  # noqa: E402
    Setpoint,
    limits_from_parameters,  # noqa: E402
)
from autopilot.identification.identify import identify_dataset  # noqa: E402
from autopilot.navigator.home import Places  # noqa: E402
from autopilot.navigator.mission_runner import MissionRunner  # noqa: E402
from autopilot.parameters import default_parameters  # noqa: E402
from contracts.airframe import PAPER, hover_rotor_speeds  # noqa: E402
from contracts.frames import DEFAULT_HOME  # noqa: E402
from ground.identify.excitation import excitation_dataset  # noqa: E402
from ground.run.inprocess import run_inprocess  # noqa: E402
from ground.scenario.scenario_file import shipped_scenarios  # noqa: E402
from sitl.plant import Plant  # noqa: E402
from tests.flight import mission_item  # noqa: E402


def per_call_us(fn, n: int, repeats: int = 7) -> float:
    fn()
    samples = []
    for _ in range(repeats):
        start = time.perf_counter()
        for _ in range(n):
            fn()
        samples.append((time.perf_counter() - start) / n * 1e6)
    return statistics.median(samples)


def main() -> None:
    models = load_models(None)
    ref = shipped_scenarios()["attitude-sine"].reference.at(1.0)
    pos_ref = shipped_scenarios()["position-sine"].reference.at(1.0)
    plant = Plant(PAPER, "paper", position_ned_m=(0, 0, -1),
                  rotor_rad_s=hover_rotor_speeds(PAPER))
    meas = plant.true_measurement()
    print("Controller step (all channels + mixer), median us per call:")
    for kind in ("ivfc", "t1fc", "smc", "pid"):
        ctrl = make_controller(kind, PAPER, 0.01, models)
        att = per_call_us(lambda c=ctrl: c.step(meas, ref, False), 20000)
        pos = per_call_us(lambda c=ctrl: c.step(meas, pos_ref, True), 20000)
        print(f"  {kind:<5} attitude mode {att:6.2f} us   position mode {pos:6.2f} us")
    print("Setpoint shaper step (autopilot/flight_tasks/shaping.py), median us per call:")
    limits = limits_from_parameters(default_parameters())
    for what, setpoint in (
            ("position 50 m away", Setpoint(np.array([50.0, 0.0, -10.0]), yaw_rad=1.0)),
            ("velocity", Setpoint(velocity_ned_mps=np.array([2.0, 1.0, -0.5]),
                                  yaw_rate_rad_s=0.3))):
        shaper = SetpointShaper()
        shaper.reset(np.zeros(3), np.zeros(3), 0.0)
        us = per_call_us(lambda s=shaper, sp=setpoint: s.step(sp, limits, 0.01), 20000)
        print(f"  {what:<20} {us:6.2f} us")
    print("Mission navigator (autopilot/navigator/mission_runner.py), median us per call:")
    runner = MissionRunner(tuple(mission_item(i, 30.0 * (i % 2), 30.0 * (i // 2), 5.0)
                                 for i in range(6)), default_parameters(),
                           Places.at(DEFAULT_HOME))
    runner.start(0, np.array([0.0, 0.0, -5.0]), 0.0, False, 2.5)
    here = np.array([10.0, 0.5, -5.0])
    us = per_call_us(lambda: runner.step(1.0, here, here), 20000)
    print(f"  {'goal on a leg':<20} {us:6.2f} us")
    print("Plant step, median us:")
    for fidelity in ("paper", "rigid-body"):
        p = Plant(PAPER, fidelity, rotor_rad_s=hover_rotor_speeds(PAPER))
        p.set_motor_commands(np.full(4, 0.47))
        one = per_call_us(lambda p=p: p.advance(0.001), 20000)
        period = per_call_us(lambda p=p: p.advance(0.01), 5000)
        print(f"  {fidelity:<10} one 1 ms RK4 step {one:6.2f} us   one 10 ms control period "
              f"(10 steps) {period:6.2f} us")
    start = time.perf_counter()
    data = excitation_dataset(PAPER)
    fly = time.perf_counter() - start
    start = time.perf_counter()
    identify_dataset(data)
    ident = time.perf_counter() - start
    print(f"Identification: excitation flight {fly:.2f} s + identification (3 channels, GK, "
          f"EDA, fits, LS) {ident:.2f} s")
    print("In-process real-time factor (20 s scenarios, 100 Hz control, 1 kHz plant), median of 3:")
    for name, scenario in shipped_scenarios().items():
        if scenario.plan is not None:  # a mission flies only through the processes
            continue
        for kind in ("ivfc",):
            run_inprocess(scenario, kind, "paper", PAPER, models)
            walls = [run_inprocess(scenario, kind, "paper", PAPER, models).wall_time_s
                     for _ in range(3)]
            wall = statistics.median(walls)
            print(f"  {name:<15} {kind}: {scenario.duration_s / wall:6.0f}x real time "
                  f"({wall * 1e3:.0f} ms wall)")


if __name__ == "__main__":
    main()
