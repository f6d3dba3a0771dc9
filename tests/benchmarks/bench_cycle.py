"""CPU of one lockstep cycle on each side (simulator, autopilot), measured in one process.

    python tests/benchmarks/bench_cycle.py                 # best of 7 rounds of 2000 cycles
    python tests/benchmarks/bench_cycle.py --scenario position-sine --rounds 5
    python tests/benchmarks/bench_cycle.py --profile       # and cProfile each side

Why in process: the two processes alternate, so each one's Python per cycle is wall time
of the run, but a run through the processes measures it only in whole (and the machine
moves under it). Here both sides are built as a scenario run builds them (the command
lines of ``ground.run.processes.vehicle_commands``, each process's own ``run`` with its
loop not started), each with a real Zenoh session that connects nowhere (records are
built, batched and put as in a run), and they alternate over a socket pair as over TCP:

* simulator: ``next_sample`` (requests, perturbations, the truth record, sensors, the
  messages packed), the send, reading and applying the answer, ``advance``;
* autopilot: ``_on_sim_readable`` (read and decode, navigation, the control step, the
  answer sent, the step's telemetry and mirror).

Figures: each round's mean per cycle, the best round's, in thread CPU time
(time.thread_time: the machine's other load does not count, as it does in wall time).
The sides and their parts are timed by stamps inside the cycle, less what a stamp
itself costs (measured first); the parts in rounds of their own with the pieces wrapped
(a part includes the wrapping of the parts inside it; the sides' figures come from
unwrapped rounds). Prints figures; asserts nothing.
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import socket
import sys
import time
from collections.abc import Callable
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

import autopilot.__main__ as autopilot_main  # noqa: E402
import sitl.__main__ as sitl_main  # noqa: E402
from autopilot.process.loop import Autopilot  # noqa: E402
from contracts.mavlink import SIM_TCP_PORT  # noqa: E402
from ground.run.processes import RunSettings, vehicle_commands  # noqa: E402
from ground.scenario.scenario_file import scenario_by_name  # noqa: E402
from sitl.server import Simulator  # noqa: E402

WARM_UP_CYCLES = 300
CLOCK = time.thread_time


def stamp_cost_s() -> float:
    """What one interval between two stamps costs when nothing runs between them."""
    clock, n = CLOCK, 20_000
    best = float("inf")
    for _ in range(5):
        total = 0.0
        for _ in range(n):
            t0 = clock()
            total += clock() - t0
        best = min(best, total / n)
    return best


STAMP_S = stamp_cost_s()


def built(module, cls: type, argv: list[str]):
    """The object ``module.run`` builds from ``argv`` (its command line after ``-m X``),
    its loop not started; Zenoh on, connecting to nothing and listening nowhere."""
    args = module.build_parser().parse_args(argv)
    args.zenoh_connect, args.zenoh_listen = ["none"], ["none"]
    captured = []
    run = cls.run
    cls.run = lambda self: captured.append(self) or 0
    try:
        module.run(args)
    finally:
        cls.run = run
    return captured[0]


class Pair:
    """A simulator and an autopilot over a socket pair, one lockstep cycle at a time."""

    def __init__(self, scenario_name: str) -> None:
        scenario = scenario_by_name(scenario_name)
        sim_argv, ap_argv = vehicle_commands(scenario, RunSettings("ivfc", "paper", "paper"),
                                             SIM_TCP_PORT, "tcp/127.0.0.1:7447")
        quiet = lambda text: None  # noqa: E731
        self.sim: Simulator = built(sitl_main, Simulator, sim_argv[3:])
        self.sim.log = quiet
        self.sim.started = True  # released, as a run's ground station releases it
        self.ap: Autopilot = built(autopilot_main, Autopilot, ap_argv[3:])
        self.ap.log = quiet
        self.ap.max_steps = float("inf")
        self.sim_end, ap_end = socket.socketpair()
        ap_end.setblocking(False)
        self.ap.sim.sock = ap_end
        self.ap._warm_up()

    def close(self) -> None:
        self.ap.sim.close()
        self.sim_end.close()
        self.ap.node.close()
        self.sim.telemetry.node.close()

    def cycles(self, n: int) -> tuple[float, float, float]:
        """``n`` cycles: CPU of the whole, of the simulator's side, of the autopilot's
        [s]."""
        sim, ap, conn = self.sim, self.ap, self.sim_end
        clock = CLOCK
        sim_s = ap_s = 0.0
        cpu0 = clock()
        for _ in range(n):
            t0 = clock()
            conn.sendall(sim.next_sample())
            t1 = clock()
            ap._on_sim_readable()
            t2 = clock()
            for msg in sim.link.read(conn):
                if msg.get_type() == "HIL_ACTUATOR_CONTROLS" and msg.time_usec == sim.time_us:
                    sim.apply_actuators(msg)
            sim.advance()
            t3 = clock()
            sim_s += (t1 - t0) + (t3 - t2)
            ap_s += t2 - t1
        return clock() - cpu0, sim_s - 2 * n * STAMP_S, ap_s - n * STAMP_S


class Parts:
    """Wall time spent in named methods, accumulated while they are wrapped."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = {}
        self._undo: list[Callable[[], None]] = []

    def wrap(self, label: str, owner: object, name: str) -> None:
        inner = getattr(owner, name)
        self.seconds[label] = 0.0
        clock, seconds, stamp_s = CLOCK, self.seconds, STAMP_S

        def timed(*args, **kwargs):
            t0 = clock()
            try:
                return inner(*args, **kwargs)
            finally:
                seconds[label] += clock() - t0 - stamp_s

        setattr(owner, name, timed)
        self._undo.append(lambda: delattr(owner, name) if name in vars(owner)
                          else None)

    def reset(self) -> None:
        for label in self.seconds:
            self.seconds[label] = 0.0

    def unwrap(self) -> None:
        for undo in reversed(self._undo):
            undo()
        self._undo.clear()


def wrap_parts(pair: Pair) -> Parts:
    """The pieces of each side, wrapped on their instances (indented: inside the one
    above)."""
    sim, ap = pair.sim, pair.ap
    parts = Parts()
    for label, owner, name in (
            ("sim next_sample", sim, "next_sample"),
            ("  publish_state", sim.telemetry, "publish_state"),
            ("  samples.frames", sim.samples, "frames"),
            ("    sensors.read", sim.samples.sensors, "read"),
            ("sim link.read", sim.link, "read"),
            ("sim apply_actuators", sim, "apply_actuators"),
            ("sim advance", sim, "advance"),
            ("  plant.advance", sim.plant, "advance"),
            ("  plant.state", sim.plant, "state"),
            ("  samples.observe", sim.samples, "observe"),
            ("ap sim.read", ap.sim, "read"),
            ("ap navigation.measurements", ap.navigation, "measurements"),
            ("ap _control", ap, "_control"),
            ("  vehicle.sample", ap.vehicle, "sample"),
            ("  vehicle.control", ap.vehicle, "control"),
            ("ap _answer", ap, "_answer"),
            ("  publish_step", ap.telemetry, "publish_step"),
            ("  end_step", ap.telemetry, "end_step")):
        parts.wrap(label, owner, name)
    return parts


def best_of(rounds: int, measure: Callable[[], tuple]) -> list[float]:
    """Each figure's best (lowest) over ``rounds`` calls of ``measure``."""
    best = list(measure())
    for _ in range(rounds - 1):
        best = [min(a, b) for a, b in zip(best, measure(), strict=True)]
    return best


def profile(pair: Pair, n: int) -> None:
    """cProfile of ``n`` cycles, each side's functions by their own time."""
    prof = cProfile.Profile()
    prof.enable()
    pair.cycles(n)
    prof.disable()
    pstats.Stats(prof).sort_stats("tottime").print_stats(40)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default="attitude-sine")
    parser.add_argument("--rounds", type=int, default=7)
    parser.add_argument("--cycles", type=int, default=2000, help="per round")
    parser.add_argument("--profile", action="store_true", help="and cProfile the cycle")
    args = parser.parse_args()
    pair = Pair(args.scenario)
    try:
        measure(pair, args)
    finally:
        pair.close()


def measure(pair: Pair, args: argparse.Namespace) -> None:
    """The figures, printed."""
    n = args.cycles
    pair.cycles(WARM_UP_CYCLES)
    cpu_s, sim_s, ap_s = best_of(args.rounds, lambda: pair.cycles(n))
    parts = wrap_parts(pair)

    def parted() -> list[float]:
        parts.reset()
        pair.cycles(n)
        return list(parts.seconds.values())

    part_s = best_of(args.rounds, parted)
    parts.unwrap()
    print(f"{args.scenario}: best of {args.rounds} rounds of {n} cycles, per cycle [us]")
    print(f"  cycle (both sides, this harness)    {1e6 * cpu_s / n:7.1f}")
    print(f"  simulator side                      {1e6 * sim_s / n:7.1f}")
    print(f"  autopilot side                      {1e6 * ap_s / n:7.1f}")
    print("parts (wrapped; best round of each):")
    for label, seconds in zip(parts.seconds, part_s, strict=True):
        print(f"  {label:34s}{1e6 * seconds / n:7.1f}")
    if args.profile:
        profile(pair, n)


if __name__ == "__main__":
    main()
