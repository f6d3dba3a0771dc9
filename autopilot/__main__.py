"""``python -m autopilot`` / ``ivfm autopilot``: the autopilot process."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

from contracts import AUTOPILOT, timeline

if TYPE_CHECKING:
    from autopilot.commander.commander import Commander
    from autopilot.trajectories import Reference
    from contracts.airframe_file import AirframeSpec

if __name__ == "__main__":
    timeline.mark(AUTOPILOT, "main")  # before the heavy imports below

from contracts.arguments import (  # noqa: E402
    ALTITUDE_M,
    AUTOPILOT_RT_PRIORITY,
    DURATION_S,
    PORT,
    RATE_HZ,
    RT_PRIORITY,
    VEHICLE_ID,
    add_vehicle_process_arguments,
    address,
    number,
)
from contracts.frames import home_argument  # noqa: E402
from contracts.mavlink import (  # noqa: E402
    API_LOCAL_PORT,
    API_UDP_PORT,
    GCS_LOCAL_PORT,
    GCS_UDP_PORT,
    SIM_TCP_PORT,
)
from contracts.modes import FLAVOURS  # noqa: E402
from contracts.paced_loop import MAX_SPIN_S, SPIN_S  # noqa: E402
from contracts.process_main import place_process, run_main, start_process  # noqa: E402
from contracts.zenoh_link import (  # noqa: E402
    VEHICLE_CONNECT,
    VEHICLE_LISTEN,
    add_zenoh_arguments,
    zenoh_options_from_args,
)


def param_argument(text: str) -> tuple[str, float]:
    """argparse type for NAME=VALUE (also used by ``ivfm run``)."""
    from autopilot.parameters import parse_assignment

    try:
        return parse_assignment(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def reference_from_options(kind: str, altitude_m: float, options: Sequence[str],
                           airframe: AirframeSpec) -> Reference:
    """``--reference KIND --reference-option NAME=VALUE ...``; an excitation given no
    envelope flies the airframe file's ``[envelope]`` (the paper's when it names none)."""
    from autopilot.trajectories import ENVELOPE_OPTIONS, REFERENCE_OPTIONS, Reference
    from contracts.airframe_file import PAPER_ENVELOPE

    fields: dict[str, float] = {}
    for item in options:
        name, _, value = item.partition("=")
        if name not in REFERENCE_OPTIONS:
            raise ValueError(f"--reference-option: unknown field {name!r}; known: "
                             f"{', '.join(REFERENCE_OPTIONS)}")
        try:
            fields[name] = float(value)
        except ValueError:
            raise ValueError(f"--reference-option {name}: {value!r} is not a number") \
                from None
    if kind == "excitation" and not fields.keys() & set(ENVELOPE_OPTIONS):
        envelope = airframe.envelope or PAPER_ENVELOPE
        fields.update(zip(ENVELOPE_OPTIONS, envelope, strict=True))
    return Reference(kind, altitude_m=altitude_m, **fields)


def build_parser(parser: argparse.ArgumentParser | None = None) -> argparse.ArgumentParser:
    from autopilot.control.factory import CONTROLLERS
    from autopilot.trajectories import REFERENCE_KINDS
    from contracts.airframe import DEFAULT_AIRFRAME
    from contracts.airframe_file import spec_argument
    from contracts.mavlink import STATE_SOURCES

    p = parser or argparse.ArgumentParser(prog="python -m autopilot", description=__doc__)
    p.add_argument("--sim", type=address, default=("127.0.0.1", SIM_TCP_PORT),
                   metavar="HOST:PORT", help="the simulator's TCP address")
    mode = p.add_mutually_exclusive_group()
    mode.add_argument("--lockstep", dest="lockstep", action="store_true", default=True,
                      help="answer every simulator sample (default)")
    mode.add_argument("--realtime", dest="lockstep", action="store_false",
                      help="run on a wall-clock timer")
    p.add_argument("--rate-hz", type=RATE_HZ, default=100.0,
                   help="control rate, 1-1000 Hz")
    p.add_argument("--state-source", default="auto", choices=list(STATE_SOURCES),
                   help="auto: ODOMETRY when the simulator sends it, else HIL_STATE_QUATERNION")
    p.add_argument("--controller", default="ivfc", choices=CONTROLLERS)
    # PX4 SITL's default vehicle is the x500: scripts written against it expect its
    # thrust (the paper's airframe hovers at 22 % and climbs at 2 g on PX4's 0.5-0.6).
    p.add_argument("--airframe", default=DEFAULT_AIRFRAME, type=spec_argument,
                   help="shipped airframe name or airframe .toml file (default: "
                        f"{DEFAULT_AIRFRAME}, the x500-sized quad X; scenarios name theirs)")
    p.add_argument("--model", type=Path, help="fuzzy model JSON (default: the shipped one)")
    p.add_argument("--any-airframe-model", action="store_true",
                   help="fly a model identified on another airframe")
    p.add_argument("--param", type=param_argument, action="append", default=[],
                   metavar="NAME=VALUE")
    p.add_argument("--flavour", default="px4", choices=FLAVOURS,
                   help="how the vehicle presents itself to ground tools")
    p.add_argument("--gcs", type=address, default=("127.0.0.1", GCS_UDP_PORT),
                   metavar="HOST:PORT", help="ground-station link target (or none)")
    p.add_argument("--gcs-bind", type=PORT, default=GCS_LOCAL_PORT, metavar="PORT",
                   help="the ground-station link's own UDP port (0: any)")
    p.add_argument("--api", type=address, default=("127.0.0.1", API_UDP_PORT),
                   metavar="HOST:PORT", help="offboard-API link target (or none)")
    p.add_argument("--api-bind", type=PORT, default=API_LOCAL_PORT, metavar="PORT")
    p.add_argument("--max-peers", type=number(0, 64, integer=True), default=4, metavar="N",
                   help="addresses per ground link that get telemetry (0-64; a newcomer "
                        "takes the place of one silent for 3 s)")
    p.add_argument("--rt-priority", type=RT_PRIORITY, default=AUTOPILOT_RT_PRIORITY, metavar="N",
                   help="real time: SCHED_FIFO priority of the control loop (1-99; 0: "
                        "normal scheduling; needs CAP_SYS_NICE, else normal with a note)")
    p.add_argument("--spin-us", type=number(0, MAX_SPIN_S * 1e6, "us"), default=SPIN_S * 1e6,
                   metavar="US",
                   help=f"real time: the last stretch before each control step busy-waited, "
                        f"so that a step starts on its deadline to the microsecond (0-"
                        f"{MAX_SPIN_S * 1e6:g}; default {SPIN_S * 1e6:g}); 0 sleeps to it "
                        "instead: the kernel's wake-up latency late, for 2-3 %% of a CPU "
                        "less at 100 Hz (several vehicles on one machine)")
    p.add_argument("--signing-state", type=Path, metavar="FILE",
                   help="where the MAVLink signing clock and stream timestamps are kept "
                        "across restarts, so a replay of frames from before one is refused "
                        "(default: $XDG_STATE_HOME/ivfm/signing-SYSID.json)")
    p.add_argument("--signing-key", metavar="HEX",
                   help="MAVLink 2 signing: 64 hex digits (32 bytes); unsigned commands are "
                        "then ignored")
    p.add_argument("--reference", choices=REFERENCE_KINDS,
                   help="offer the onboard reference generator of a paper scenario")
    p.add_argument("--altitude", type=ALTITUDE_M, default=1.0, help="reference altitude [m]")
    p.add_argument("--reference-option", action="append", default=[], metavar="NAME=VALUE",
                   help="another reference field (yaw_rad, amplitude, hold_start_s, "
                        "hold_end_s, seed, rate_rad_s, yaw_rate_rad_s; repeatable); an "
                        "excitation given none of amplitude, rate_rad_s, yaw_rate_rad_s flies "
                        "the airframe file's [envelope]")
    p.add_argument("--schedule", type=Path,
                   help="perturbation schedule JSON (sim time); the autopilot takes the kicks")
    p.add_argument("--arm-in-reference", action="store_true",
                   help="scenario runs: armed in REFERENCE mode from the first sample")
    p.add_argument("--mission", type=Path, metavar="PLAN",
                   help="a QGroundControl .plan: its mission, fence and rally points stored "
                        "at start, as if uploaded")
    p.add_argument("--start-mission", action="store_true",
                   help="scenario runs: fly the --mission from the ground, armed in "
                        "AUTO.MISSION as soon as arming is allowed")
    p.add_argument("--duration", type=DURATION_S, default=float("inf"), metavar="S",
                   help="stop after this much sim time of control")
    p.add_argument("--sysid", type=VEHICLE_ID, default=1, metavar="ID",
                   help="MAVLink system id, also the vehicle id in telemetry keys (1-255)")
    p.add_argument("--home", type=home_argument, metavar="NAME|LAT,LON,ALT",
                   help="where on Earth the local frame is: a named home (CMAC, PX4, ...: "
                        "docs/mavlink.md) or degrees, degrees, metres AMSL "
                        "(default: the simulator's first HIL_STATE_QUATERNION, as PX4 "
                        "takes it); south or west: --home=-33.86,151.21,40")
    add_vehicle_process_arguments(p)
    add_zenoh_arguments(p, VEHICLE_LISTEN, VEHICLE_CONNECT, identity="vehicle", vehicle=True)
    return p


def preload() -> None:
    """What a run imports, and the compiled code of the default vehicle's steps (the
    controller, the shaper, the sample's conversions), loaded once by the process loader
    (contracts/zygote.py): in each process of a run that code took about 0.1 s of its
    start, on the critical path. Another controller's code, and the estimator's filter
    steps (0.1 s that every run would pay here), load in the autopilots that use them,
    before their loops."""
    import autopilot.mavlink.server  # noqa: F401
    import autopilot.process.loop  # noqa: F401
    from autopilot.process.sim_link import SimLink
    from autopilot.process.warm_up import load_compiled_code
    from contracts.mavlink import STATE_SOURCES

    args = build_parser().parse_args([])
    vehicle = make_vehicle(args)
    for source in STATE_SOURCES:  # each decodes its own messages
        load_compiled_code(vehicle, 1.0 / args.rate_hz, SimLink("127.0.0.1", 0, source),
                           filter_steps=False)


def make_vehicle(args: argparse.Namespace) -> Commander:
    """The vehicle of the command line: airframe, parameters, controller, reference,
    schedule and mission."""
    from autopilot.commander.commander import Commander
    from autopilot.control.factory import load_models, make_controller
    from autopilot.parameters import airframe_parameters, validate_parameters
    from contracts.airframe import airframe_from_spec
    from contracts.perturbations import load_schedule

    spec = args.airframe  # the airframe file, read once by the command line (spec_argument)
    airframe = airframe_from_spec(spec)
    # The airframe file's own defaults, then the command line's.
    parameters = validate_parameters({**airframe_parameters(spec), **dict(args.param)})
    models = (load_models(args.model, spec, args.any_airframe_model)
              if args.controller in ("ivfc", "t1fc") else None)
    period_s = 1.0 / args.rate_hz
    reference = None
    if args.reference:
        reference = reference_from_options(args.reference, args.altitude,
                                           args.reference_option, spec)
    if args.arm_in_reference and reference is None:
        raise ValueError("--arm-in-reference needs --reference")
    if args.start_mission and args.mission is None:
        raise ValueError("--start-mission needs --mission")
    if args.start_mission and args.arm_in_reference:
        raise ValueError("--start-mission and --arm-in-reference exclude each other")
    vehicle = Commander(lambda p: make_controller(args.controller, airframe, period_s, models, p),
                        period_s, parameters, reference,
                        load_schedule(args.schedule) if args.schedule else (), args.flavour)
    if args.mission is not None:
        from autopilot.navigator.plan_file import read_plan

        for mission_type, items in read_plan(args.mission).items():
            vehicle.mission.replace(mission_type, items)
    return vehicle


def run(args: argparse.Namespace) -> int:
    from autopilot.mavlink.link import open_link
    from autopilot.mavlink.server import MavlinkServer
    from autopilot.mavlink.signing import SigningState, default_state_path
    from autopilot.process.loop import Autopilot, AutopilotConfig
    from contracts.telemetry import check_vehicle_id

    timeline.mark(AUTOPILOT, "imports done")
    place_process(AUTOPILOT, args)
    config = AutopilotConfig(sim_host=args.sim[0], sim_port=args.sim[1], lockstep=args.lockstep,
                             rate_hz=args.rate_hz, state_source=args.state_source,
                             duration_s=args.duration, sysid=check_vehicle_id(args.sysid),
                             rt_priority=args.rt_priority,
                             zenoh=zenoh_options_from_args(args), home=args.home,
                             perturbations=args.perturbations, airframe=args.airframe,
                             handover_cpu=args.handover_cpu, spin_s=args.spin_us / 1e6)
    vehicle = make_vehicle(args)
    key = None
    if args.signing_key is not None:
        try:
            key = bytes.fromhex(args.signing_key)
        except ValueError:
            key = b""
        if len(key) != 32:
            raise ValueError("--signing-key must be 64 hex digits (32 bytes)")
    links = [open_link("gcs", ("0.0.0.0", args.gcs_bind), args.gcs, key, 0, config.sysid,
                       args.flavour)]
    if args.api is not None or args.api_bind:
        links.append(open_link("api", ("0.0.0.0", args.api_bind), args.api, key, 1,
                               config.sysid, args.flavour))
    state = SigningState(args.signing_state or default_state_path(config.sysid))
    restored = state.restore([link.mav.signing for link in links])  # also for SETUP_SIGNING
    if key is not None:
        print(f"autopilot: {restored}", file=sys.stderr)
    ground = MavlinkServer(vehicle, links, args.flavour, sysid=config.sysid,
                           max_peers=args.max_peers, signing_state=state)
    return Autopilot(config, vehicle, ground, arm_in_reference=args.arm_in_reference,
                     start_mission=args.start_mission).run()


def main(argv: Sequence[str] | None = None) -> int:
    """The autopilot's command line, run once (contracts/process_main.py)."""
    return run_main(AUTOPILOT, build_parser, run, argv)


if __name__ == "__main__":
    start_process(AUTOPILOT, main)
