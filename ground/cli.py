"""The ``ivfm`` command: run scenarios, compare controllers, identify fuzzy models.

Every argument is validated before anything is written: a bad name, file or number
gives ``ivfm: error: ...`` on stderr, exit code 2, and no output files.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Sequence
from pathlib import Path

from contracts.arguments import RATE_HZ, SEED, TIMEOUT_S, VEHICLE_ID, cpu_list, number


def _add_common(p: argparse.ArgumentParser) -> None:
    from autopilot.__main__ import param_argument
    from contracts.airframe import airframe_argument

    p.add_argument("--airframe", default="paper", type=airframe_argument,
                   help="shipped airframe name or airframe .toml file")
    p.add_argument("--model", type=Path, help="fuzzy model JSON (default: the shipped one)")
    p.add_argument("--any-airframe-model", action="store_true",
                   help="fly a model identified on another airframe")
    p.add_argument("--param", type=param_argument, action="append", default=[],
                   metavar="NAME=VALUE", help="controller parameter override (repeatable)")


def _run_parser(run: argparse.ArgumentParser) -> None:
    from autopilot.control.factory import CONTROLLERS
    from contracts.frames import home_argument
    from contracts.mavlink import STATE_SOURCES
    from ground.live_view import view_address
    from ground.scenarios import shipped_names
    from sitl.dynamics import FIDELITIES
    from sitl.sensors import profile_argument

    run.add_argument("scenario", help=f"one of: {', '.join(shipped_names())}; or a scenario .toml")
    pace = run.add_mutually_exclusive_group()
    pace.add_argument("--inprocess", action="store_true",
                      help="plant and controller in one process (no MAVLink)")
    pace.add_argument("--realtime", action="store_true",
                      help="the two processes paced to the wall clock (default: lockstep)")
    run.add_argument("--rate-hz", type=RATE_HZ, default=100.0,
                     help="control rate, 1-1000 Hz (default 100)")
    _add_rt_cpus(run)
    run.add_argument("--view", type=view_address, metavar="[HOST:]PORT",
                     help="serve the flight live to Foxglove on this WebSocket port while it "
                          "flies (e.g. 8765; docs/telemetry.md#foxglove)")
    run.add_argument("--state-source", choices=list(STATE_SOURCES),
                     help="what the autopilot flies on: the simulator's truth (auto, odometry, "
                          "hil-state) or its estimator on the sensors (default: the "
                          "scenario's, else auto)")
    run.add_argument("--sensors", type=profile_argument,
                     help="the simulator's sensor profile: ideal, typical, degraded or a "
                          ".toml file (default: the scenario's, else ideal)")
    run.add_argument("--seed", type=SEED, default=0,
                     help="seed of the simulator's sensors and link loss (default 0)")
    run.add_argument("--home", type=home_argument, metavar="LAT,LON,ALT",
                     help="where on Earth the flight is: degrees, degrees, metres AMSL "
                          "(default: the scenario's, else PX4's SITL home in Zurich); "
                          "south or west: --home=-33.86,151.21,40")
    run.add_argument("--controller", choices=CONTROLLERS, help="(default: the scenario's)")
    run.add_argument("--plant", choices=list(FIDELITIES), help="(default: the scenario's)")
    run.add_argument("--out", type=Path, default=None,
                     help="the run folder (default: a new one under runs/ named after the "
                          "scenario)")
    run.add_argument("--no-figures", action="store_true")
    _add_common(run)
    run.set_defaults(airframe=None)


def _check_parser(check: argparse.ArgumentParser) -> None:
    check.add_argument("paths", nargs="*", metavar="PATH",
                       help="scenario files, folders of them, or shipped names (default: "
                            "every shipped scenario)")
    check.add_argument("--out", type=Path, default=None,
                       help="folder for the run folders and check.json (default: a new "
                            "folder under runs/)")
    check.add_argument("--junit", type=Path, metavar="FILE", help="write JUnit XML here")
    check.add_argument("--summary", type=Path, metavar="FILE",
                       help="append a Markdown summary here (default: $GITHUB_STEP_SUMMARY "
                            "when set)")
    check.add_argument("--baseline", type=Path, metavar="DIR",
                       help="an earlier check's folder (or its check.json): fail on drift")
    check.add_argument("--tolerance", type=number(0.0, 10.0), default=0.05,
                       help="relative change a baseline allows (default 0.05)")
    check.add_argument("-j", "--jobs", type=number(1, 64, integer=True), default=1,
                       help="scenarios at a time, 1-64 (default 1)")
    check.add_argument("--realtime", action="store_true",
                       help="pace to the wall clock (default: lockstep)")
    _add_rt_cpus(check)
    check.add_argument("--cold", action="store_true",
                       help="new processes for every scenario (default: kept warm)")
    check.add_argument("--keep", action="store_true",
                       help="keep the run folders of passed scenarios too")


def _rehearse_parser(p: argparse.ArgumentParser) -> None:
    from autopilot.__main__ import param_argument
    from sitl.sensors import profile_argument

    p.add_argument("--airframe", required=True,
                   help="the airframe to rehearse: a shipped name or an airframe .toml file "
                        "(read even when its rotors cannot fly it, to say why)")
    p.add_argument("--model", type=Path, help="fuzzy model JSON (default: the airframe's "
                   "shipped one, else one identified on it now)")
    p.add_argument("--rate-hz", type=RATE_HZ, default=100.0,
                   help="control rate of the flights, 1-1000 Hz (default 100)")
    p.add_argument("--sensors", type=profile_argument,
                   help="sensor profile of the flights on the estimator: ideal, "
                   "typical, degraded or a .toml file (default: each flight's, typical)")
    p.add_argument("--profile", default="default",
                   help="readiness profile: default (shipped) or a .toml file")
    p.add_argument("--param", type=param_argument, action="append", default=[],
                   metavar="NAME=VALUE", help="a parameter of the vehicle (repeatable)")
    p.add_argument("--out", type=Path, default=None,
                   help="rehearsal folder (default: a new one under runs/)")
    p.add_argument("--junit", type=Path, metavar="FILE",
                   help="also write the JUnit XML here (it is always in the folder)")
    _add_rt_cpus(p)


def _add_rt_cpus(p: argparse.ArgumentParser) -> None:
    p.add_argument("--rt-cpus", type=cpu_list, metavar="LIST",
                   help="keep the simulator and autopilot on these CPUs (with 'ivfm "
                        "shield': CPUs nothing else runs on; docs/realtime.md)")


def _report_parser(rep: argparse.ArgumentParser) -> None:
    rep.add_argument("run_dir", type=Path, help="a folder written by ivfm run")
    rep.add_argument("--no-figures", action="store_true")


def _compare_parser(compare: argparse.ArgumentParser) -> None:
    from autopilot.control.factory import CONTROLLERS
    from ground.scenarios import PAPER_SCENARIOS
    from sitl.dynamics import FIDELITIES

    compare.add_argument("--out", type=Path, default=None,
                         help="the comparison's folder (default: a new one under runs/)")
    compare.add_argument("--scenarios", nargs="+", default=list(PAPER_SCENARIOS))
    compare.add_argument("--controllers", nargs="+", default=list(CONTROLLERS))
    compare.add_argument("--plants", nargs="+", default=list(FIDELITIES))
    _add_common(compare)


def _identify_parser(ident: argparse.ArgumentParser) -> None:
    from contracts.airframe import airframe_argument
    from ground.excitation import MIN_SAMPLES

    ident.add_argument("--data", type=Path, help="dataset CSV (default: fly the excitation)")
    ident.add_argument("--log", type=Path, metavar="MCAP_OR_RUN_DIR",
                       help="identify from a logged flight (see docs/scenarios.md)")
    ident.add_argument("--vehicle", type=VEHICLE_ID, default=1, help="vehicle id in the log")
    ident.add_argument("--out", type=Path, default=None, help="model JSON to write")
    ident.add_argument("--write-data", type=Path, help="also save the generated excitation CSV")
    ident.add_argument("--seed", type=SEED, default=0)
    ident.add_argument("--samples", type=number(MIN_SAMPLES, 10_000_000, integer=True),
                       default=4000, help=f"excitation samples, at least {MIN_SAMPLES}")
    ident.add_argument("--clusters", type=number(2, 20, integer=True), default=None,
                       help="fuzzy clusters per model, 2-20 (default: the airframe's)")
    ident.add_argument("--airframe", default="paper", type=airframe_argument,
                       help="shipped airframe name or airframe .toml file")
    ident.add_argument("--envelope", type=envelope_argument, default=None,
                       metavar="ATTITUDE_RAD,RATE_RAD_S[,YAW_RATE_RAD_S]",
                       help="what the model will fly, which the data must cover; yaw rate "
                            "half the rate if not given (default: the airframe file's "
                            "[envelope], else 1 rad, 1 rad/s, 0.5 rad/s)")
    ident.add_argument("--allow-narrow", action="store_true",
                       help="write the model even if the data does not cover the envelope")


def envelope_argument(text: str) -> tuple[float, ...]:
    """ATTITUDE_RAD,RATE_RAD_S[,YAW_RATE_RAD_S], each positive and bounded."""
    from contracts.airframe_file import ENVELOPE_LIMITS

    parts = text.split(",")
    if len(parts) not in (2, 3):
        raise argparse.ArgumentTypeError(
            f"expected ATTITUDE_RAD,RATE_RAD_S[,YAW_RATE_RAD_S], got {text!r}")
    values = []
    for part, (name, high) in zip(parts, ENVELOPE_LIMITS.items(), strict=False):
        try:
            values.append(number(0.0, high, low_open=True)(part.strip()))
        except argparse.ArgumentTypeError as exc:
            raise argparse.ArgumentTypeError(f"{name} {exc}") from None
    return tuple(values) if len(values) == 3 else (*values, 0.5 * values[1])


def _sitl_parser(p: argparse.ArgumentParser) -> None:
    from sitl.__main__ import build_parser

    build_parser(p)


def _autopilot_parser(p: argparse.ArgumentParser) -> None:
    from autopilot.__main__ import build_parser

    build_parser(p)


def _plan_parser(plan: argparse.ArgumentParser) -> None:
    plan.add_argument("file", type=Path, help="the .plan file")
    plan.add_argument("--connect", default="udpin:0.0.0.0:14550",
                      help="where the vehicle's ground link arrives (default: "
                           "udpin:0.0.0.0:14550, where QGroundControl listens)")
    plan.add_argument("--timeout", type=TIMEOUT_S, default=30.0,
                      help="seconds to wait for the vehicle's heartbeat")


def _shield_parser(shield: argparse.ArgumentParser) -> None:
    which = shield.add_mutually_exclusive_group(required=True)
    which.add_argument("--cpus", type=cpu_list, metavar="LIST",
                       help="the CPUs to keep for the real-time processes (0, 0-1)")
    which.add_argument("--off", action="store_true", help="every CPU for everything again")


def _no_arguments(_p: argparse.ArgumentParser) -> None:
    pass


def _campaign_parser(p: argparse.ArgumentParser) -> None:
    p.add_argument("campaign", help="a shipped campaign (ivfm campaigns) or a campaign .toml")
    p.add_argument("--out", type=Path,
                   help="the campaign folder (default runs/NAME; the same folder resumes)")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="a running Dask scheduler (tcp://HOST:8786) instead of a "
                        "LocalCluster on this machine")
    p.add_argument("--workers", type=number(1, 1024, integer=True),
                   help="LocalCluster workers (default: one per CPU)")
    p.add_argument("--runs", type=number(1, 100_000, integer=True),
                   help="draws per scenario (default: the file's)")
    p.add_argument("--report-only", action="store_true",
                   help="write the report from the runs in the folder, fly nothing")


# (command, help, description, what adds its arguments): in the order ``ivfm --help`` lists.
_COMMANDS: tuple[tuple[str, str, str | None, Callable[[argparse.ArgumentParser], None]], ...] = (
    ("run", "run one scenario and write metrics.json and figures", None, _run_parser),
    ("check", "fly scenario files and judge them by their [expect] tables",
     "Fly each scenario through the processes and check its expectations (docs/checks.md). "
     "Exit status 0 when all hold, 1 when any fails, 2 on bad input.", _check_parser),
    ("rehearse", "go / no-go for a first flight of an airframe (docs/rehearsal.md)",
     "Check the airframe and parameters, then fly the readiness profile's flights through "
     "the processes and judge each (docs/rehearsal.md). Writes rehearsal.md, rehearsal.html, "
     "JUnit XML and the parameters as a QGroundControl .params file. Exit status 0 when "
     "every check passes (go), 1 when any fails (no-go), 2 on bad input.", _rehearse_parser),
    ("report", "metrics.json and figures of a run folder, from its log", None, _report_parser),
    ("compare", "every controller on every scenario, tables+figures", None, _compare_parser),
    ("identify", "build the IVFM and T1FM from input-output data", None, _identify_parser),
    ("sitl", "the simulator process (PX4 simulator protocol)", None, _sitl_parser),
    ("autopilot", "the autopilot process (MAVLink vehicle)", None, _autopilot_parser),
    ("ground", "ground station: logger, perturbations, router, .tlog export", None,
     lambda p: _ground_parsers(p)),
    ("plan", "upload a QGroundControl .plan file to a vehicle (docs/missions.md)", None,
     _plan_parser),
    ("shield", "keep CPUs for the real-time processes (docs/realtime.md)",
     "Move every user-space thread on this machine off the given CPUs (what they start "
     "later inherits it), so that the simulator and autopilot started with --rt-cpus on "
     "the same list have them to themselves. Needs root (CAP_SYS_NICE) for other users' "
     "processes. --off lifts it.", _shield_parser),
    ("campaign", "many randomized flights on Dask, summarised with statistics",
     "Fly every draw of a campaign file with every controller it names, on a Dask cluster "
     "(a LocalCluster on this machine unless --scheduler), streaming results into the "
     "folder; a rerun skips finished runs. Writes results.csv, runs/*.json, report.md, "
     "report.json and figures (docs/campaigns.md).", _campaign_parser),
    ("scenarios", "list the scenarios", None, _no_arguments),
    ("campaigns", "list the shipped campaign files", None, _no_arguments),
    ("params", "list the controller parameters with defaults", None, _no_arguments),
)


def _build_parser(argv: Sequence[str] | None = None) -> argparse.ArgumentParser:
    """The ``ivfm`` parser. Only the command named in ``argv`` gets its arguments (each
    command's imports load with them: ``ivfm ground log`` starts without the vehicle's
    compiled code); without a known command, every one does."""
    args = list(sys.argv[1:] if argv is None else argv)
    named = args[0] if args and args[0] in {c[0] for c in _COMMANDS} else None
    parser = argparse.ArgumentParser(prog="ivfm",
                                     description=__doc__.splitlines()[0].replace("``", ""))
    sub = parser.add_subparsers(dest="command", required=True)
    for name, help_text, description, add_arguments in _COMMANDS:
        p = sub.add_parser(name, help=help_text, description=description)
        if named is None or named == name:
            add_arguments(p)
    return parser


def _ground_parsers(ground: argparse.ArgumentParser) -> None:
    from contracts.perturbations import KINDS
    from contracts.telemetry import AUTOPILOT, DEFAULT_GROUND_ENDPOINT, DEFAULT_PORT, SITL
    from contracts.zenoh_link import add_security_arguments, add_zenoh_arguments
    from ground.live_view import DEFAULT_VIEW_PORT, add_view_arguments, view_address

    sub = ground.add_subparsers(dest="ground_command", required=True)
    log = sub.add_parser("log", help="record all telemetry to MCAP (docs/telemetry.md)")
    log.add_argument("--out", type=Path, required=True, help="folder for the .mcap files")
    log.add_argument("--name", default="logger", help="logger name (status key, token)")
    log.add_argument("--prefix", default="telemetry", help="file name prefix")
    log.add_argument("--chunk-kib", type=number(1, 65536, integer=True), default=256,
                     help="MCAP chunk size [KiB], 1-65536")
    log.add_argument("--flush-s", type=number(0.01, 60.0, "s"), default=0.25,
                     help="close a chunk at least this often [s], 0.01-60")
    log.add_argument("--rotate-mib", type=number(1, 1_000_000, integer=True), default=512,
                     help="start a new file past this [MiB]")
    log.add_argument("--rotate-chunks", type=number(16, 10_000_000, integer=True),
                     default=512,
                     help="... or past this many chunks (bounds the logger's memory)")
    log.add_argument("--compression", default="zstd", choices=["zstd", "lz4", "none"])
    log.add_argument("--view", type=view_address, metavar="[HOST:]PORT",
                     help="also serve the flight live to Foxglove on this WebSocket port "
                          f"(e.g. {DEFAULT_VIEW_PORT})")
    add_view_arguments(log)
    log.add_argument("--no-foxglove", action="store_true",
                     help="write only the records, not what Foxglove draws beside them")
    add_zenoh_arguments(log, [DEFAULT_GROUND_ENDPOINT], [])

    view = sub.add_parser("view", help="the flight live in Foxglove (WebSocket)",
                          description="Serves the telemetry of every vehicle heard over "
                                      "Zenoh to Foxglove (open connection, Foxglove "
                                      "WebSocket, ws://HOST:PORT; docs/telemetry.md#foxglove)."
                                      " A slow or absent viewer never slows the vehicles.")
    view.add_argument("--view", type=view_address, default=("127.0.0.1", DEFAULT_VIEW_PORT),
                      metavar="[HOST:]PORT",
                      help=f"where to serve it (default 127.0.0.1:{DEFAULT_VIEW_PORT})")
    add_view_arguments(view)
    add_zenoh_arguments(view, [], [DEFAULT_GROUND_ENDPOINT])

    kinds = "; ".join(f"{k}: {', '.join(v.params) or '-'} ({v.target})"
                      for k, v in KINDS.items())
    pert = sub.add_parser("perturb", help="inject a perturbation (acknowledged)",
                          description=f"Kinds and their NAME=VALUE fields: {kinds}. "
                                      "'list' and 'clear' show and end perturbations.")
    pert.add_argument("kind", choices=[*KINDS, "list", "clear"])
    pert.add_argument("values", nargs="*", metavar="NAME=VALUE",
                      help="fields; vectors comma-separated (ned_mps=3,0,0)")
    pert.add_argument("--vehicle", type=VEHICLE_ID, default=1)
    pert.add_argument("--start", default="now", help="sim time [s] or now (default)")
    pert.add_argument("--end", type=number(0.0, 1e9, "s"), help="sim time it ends [s]")
    pert.add_argument("--duration", type=number(0.0, 1e9, "s"),
                      help="how long [s] (instead of --end)")
    pert.add_argument("--id", help="name it (clear: the one to end)")
    pert.add_argument("--target", choices=[SITL, AUTOPILOT], help="list/clear: one side")
    pert.add_argument("--timeout", type=TIMEOUT_S, default=5.0,
                      help="seconds to wait for the ack")
    add_zenoh_arguments(pert, [], [DEFAULT_GROUND_ENDPOINT])

    router = sub.add_parser("router", help="a Zenoh router linking machines",
                            description="Links beyond this machine need certificates "
                                        "(--zenoh-tls) or --zenoh-insecure "
                                        "(docs/telemetry.md#security).")
    router.add_argument("--listen", action="append", metavar="ENDPOINT",
                        help=f"default tls/0.0.0.0:{DEFAULT_PORT} with --zenoh-tls, else "
                             f"tcp/0.0.0.0:{DEFAULT_PORT} (needs --zenoh-insecure); "
                             "repeatable")
    router.add_argument("--connect", action="append", metavar="ENDPOINT",
                        help="other routers (repeatable)")
    add_security_arguments(router, "ground")

    certs = sub.add_parser("certs", help="make test certificates for mutual TLS",
                           description="A certificate authority and one certificate per "
                                       "--name (default: ground and vehicle), for "
                                       "--zenoh-tls. Test certificates: a fleet's come "
                                       "from its own authority.")
    certs.add_argument("--out", type=Path, required=True, help="folder to write them to")
    certs.add_argument("--name", action="append", metavar="NAME",
                       help="an identity (repeatable; default: ground, vehicle)")
    certs.add_argument("--host", action="append", metavar="HOST",
                       help="a name or address the peers reach each other at (repeatable; "
                            "default: localhost, 127.0.0.1)")

    tlog = sub.add_parser("tlog", help="export the MAVLink mirror of a log as a .tlog")
    tlog.add_argument("log", type=Path, help="an .mcap file or a run folder")
    tlog.add_argument("--out", type=Path, help="the .tlog (default beside the log)")


def main(argv: Sequence[str] | None = None) -> int:
    parser = _build_parser(argv)
    args = parser.parse_args(argv)
    from ground import commands

    if args.command == "ground":
        args.command = f"ground {args.ground_command}"
    try:
        handler = {
            "report": commands.report_command,
            "check": commands.check_command,
            "rehearse": commands.rehearse_command,
            "ground log": commands.ground_log_command,
            "ground view": commands.ground_view_command,
            "ground perturb": commands.ground_perturb_command,
            "ground router": commands.ground_router_command,
            "ground certs": commands.ground_certs_command,
            "ground tlog": commands.ground_tlog_command,
            "run": commands.run_command,
            "compare": commands.compare_command,
            "identify": commands.identify_command,
            "scenarios": commands.scenarios_command,
            "campaign": commands.campaign_command,
            "campaigns": commands.campaigns_command,
            "shield": commands.shield_command,
            "params": commands.params_command,
            "sitl": commands.sitl_command,
            "autopilot": commands.autopilot_command,
            "plan": commands.plan_command,
        }[args.command]
        return handler(args)
    except (commands.UsageError, ValueError, OSError) as exc:
        print(f"ivfm: error: {exc}", file=sys.stderr)
        return 2
    except RuntimeError as exc:  # a process of the run failed: said, exit 1
        from ground.processes import ProcessRunError

        if not isinstance(exc, ProcessRunError):
            raise
        print(f"ivfm: error: {exc}", file=sys.stderr)
        return 1


def console_main() -> None:
    """The ``ivfm`` command: ``main``, then an exit without the interpreter's teardown
    (numba's, Zenoh's and matplotlib's finalizers add 0.2-0.3 s to every command; every
    file is closed by then)."""
    from contracts.warm import exit_process

    exit_process(main())


def _preload_logger() -> None:
    """What the logger of a run imports, loaded by a warm process before its first run."""
    import ground.commands  # noqa: F401
    import ground.logger  # noqa: F401


if __name__ == "__main__":  # the logger of a run (python -m ground.cli ground log ...)
    from contracts.warm import WARM_FLAG, exit_process, serve

    exit_process(serve(main, _preload_logger) if sys.argv[1:] == [WARM_FLAG] else main())
