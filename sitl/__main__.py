"""``python -m sitl`` / ``ivfm sitl``: the simulator process."""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path

from contracts import SITL, timeline

if __name__ == "__main__":
    timeline.mark(SITL, "main")  # before the heavy imports below

from contracts.airframe import DEFAULT_AIRFRAME  # noqa: E402
from contracts.airframe_file import spec_argument  # noqa: E402
from contracts.arguments import (  # noqa: E402
    ALTITUDE_M,
    DURATION_S,
    PORT,
    RT_PRIORITY,
    SEED,
    SIM_RATE_HZ,
    SIMULATOR_RT_PRIORITY,
    VEHICLE_ID,
    add_vehicle_process_arguments,
)
from contracts.frames import DEFAULT_HOME, home_argument  # noqa: E402
from contracts.mavlink import SIM_TCP_PORT  # noqa: E402
from contracts.perturbations import load_schedule  # noqa: E402
from contracts.process_main import place_process, run_main, start_process  # noqa: E402
from contracts.zenoh_link import (  # noqa: E402
    VEHICLE_CONNECT,
    VEHICLE_LISTEN,
    add_zenoh_arguments,
    zenoh_options_from_args,
)
from sitl.dynamics import FIDELITIES  # noqa: E402
from sitl.sensors import profile_argument, read_profile  # noqa: E402


def build_parser(parser: argparse.ArgumentParser | None = None) -> argparse.ArgumentParser:
    p = parser or argparse.ArgumentParser(prog="python -m sitl", description=__doc__)
    p.add_argument("--host", default="127.0.0.1", help="address to listen on")
    p.add_argument("--port", type=PORT, default=SIM_TCP_PORT, help="TCP port (PX4: 4560)")
    mode = p.add_mutually_exclusive_group()
    mode.add_argument("--lockstep", dest="lockstep", action="store_true", default=True,
                      help="wait for the autopilot each sample (default)")
    mode.add_argument("--realtime", dest="lockstep", action="store_false",
                      help="pace to the wall clock")
    p.add_argument("--rate-hz", type=SIM_RATE_HZ, default=100.0,
                   help="samples per second, 1-2000; in lockstep the autopilot's rate "
                        "or a multiple")
    p.add_argument("--plant", default="rigid-body", choices=list(FIDELITIES))
    # PX4 SITL's default vehicle is the x500: scripts written against it expect its
    # thrust (the paper's airframe hovers at 22 % and climbs at 2 g on PX4's 0.5-0.6).
    p.add_argument("--airframe", default=DEFAULT_AIRFRAME, type=spec_argument,
                   help="shipped airframe name or airframe .toml file (default: "
                        f"{DEFAULT_AIRFRAME}, the x500-sized quad X; scenarios name theirs)")
    p.add_argument("--start-altitude", type=ALTITUDE_M, default=0.0, metavar="M",
                   help="start hovering at this altitude (default: on the ground)")
    p.add_argument("--schedule", type=Path, help="perturbation schedule JSON (sim time)")
    p.add_argument("--duration", type=DURATION_S, default=float("inf"), metavar="S",
                   help="stop after this much sim time")
    p.add_argument("--exit-on-disconnect", action="store_true",
                   help="stop when the autopilot disconnects (scenario runs)")
    p.add_argument("--vehicle", type=VEHICLE_ID, default=1, metavar="ID",
                   help="vehicle id in telemetry keys (the autopilot's MAVLink system id)")
    p.add_argument("--hold", action="store_true",
                   help="lockstep: wait for a start request over Zenoh before the first sample")
    p.add_argument("--seed", type=SEED, default=0, help="seed of sensor noise and link loss")
    p.add_argument("--sensors", default="ideal", type=profile_argument,
                   help="sensor profile: ideal, typical, degraded or a .toml file "
                        "(docs/sensors.md)")
    p.add_argument("--rt-priority", type=RT_PRIORITY, default=SIMULATOR_RT_PRIORITY, metavar="N",
                   help="real time: SCHED_FIFO priority (1-99; 0: normal scheduling)")
    p.add_argument("--home", type=home_argument, default=DEFAULT_HOME,
                   metavar="NAME|LAT,LON,ALT",
                   help="where on Earth the vehicle starts: a named home (CMAC, PX4, KSFO, "
                        "...: docs/mavlink.md) or degrees, degrees, metres AMSL (default: "
                        "PX4's SITL home, 47.397742,8.545594,488); south or west: "
                        "--home=-33.86,151.21,40")
    p.add_argument("--log-sensors", action="store_true",
                   help="send the HIL_SENSOR and HIL_GPS frames of every sample to the log "
                        "too (a ULog's sensor_combined and sensor_gps; docs/ulog.md)")
    add_vehicle_process_arguments(p)
    add_zenoh_arguments(p, VEHICLE_LISTEN, VEHICLE_CONNECT, identity="vehicle", vehicle=True)
    return p


def run(args: argparse.Namespace) -> int:
    from sitl.server import Simulator, SimulatorConfig

    timeline.mark(SITL, "imports done")
    place_process(SITL, args)
    config = SimulatorConfig(
        airframe=args.airframe, fidelity=args.plant, host=args.host,
        port=args.port, lockstep=args.lockstep, rate_hz=args.rate_hz,
        start_altitude_m=args.start_altitude,
        schedule=load_schedule(args.schedule) if args.schedule else (),
        exit_on_disconnect=args.exit_on_disconnect, duration_s=args.duration,
        vehicle_id=args.vehicle, zenoh=zenoh_options_from_args(args), hold=args.hold,
        seed=args.seed, rt_priority=args.rt_priority, sensors=read_profile(args.sensors),
        home=args.home, perturbations=args.perturbations, handover_cpu=args.handover_cpu,
        log_sensors=args.log_sensors)
    return Simulator(config).run()


def preload() -> None:
    """What a run imports and the plant's compiled code, loaded once by the process
    loader (contracts/zygote.py)."""
    from sitl.server import preload_compiled_code

    preload_compiled_code()


def main(argv: Sequence[str] | None = None) -> int:
    """The simulator's command line, run once (contracts/process_main.py)."""
    return run_main(SITL, build_parser, run, argv)


if __name__ == "__main__":
    start_process(SITL, main)
