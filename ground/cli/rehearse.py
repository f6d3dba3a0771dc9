"""``ivfm rehearse``: go / no-go for a first flight of an airframe."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from autopilot.__main__ import param_argument
from contracts.airframe_file import read_airframe
from contracts.arguments import RATE_HZ
from contracts.atomic_file import write_atomic
from ground.cli.common import add_rt_cpus, fresh_folder
from ground.rehearsal.outputs import summary_lines
from ground.rehearsal.readiness import load_profile
from ground.rehearsal.rehearse import rehearse
from ground.run.progress import LiveLine
from ground.run.reference import CHOICES
from sitl.sensors import profile_argument

DESCRIPTION = (
    "Check the airframe and parameters, then fly the readiness profile's flights through "
    "the processes and judge each (docs/rehearsal.md). Writes rehearsal.md, rehearsal.html, "
    "JUnit XML and the parameters as a QGroundControl .params file. Exit status 0 when "
    "every check passes (go), 1 when any fails (no-go), 2 on bad input.")


def add_arguments(p: argparse.ArgumentParser) -> None:
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
    add_rt_cpus(p)
    p.add_argument("--reference", choices=(*CHOICES, "none"), default="auto",
                   help="the sleeper beside each real-time flight, whose lost periods are "
                        "the machine's own (auto: cyclictest when installed, else the "
                        "built-in one; docs/realtime.md)")


def handle(args: argparse.Namespace) -> int:
    # A file that cannot be read (a draft with numbers TO_FILL among them) is refused
    # before anything is written.
    read_airframe(args.airframe, controllable=False)
    profile = load_profile(args.profile)
    out = args.out or fresh_folder("rehearse")
    print(f"ivfm rehearse: {args.airframe}, profile {profile.name} ({len(profile.flights)} "
          f"flights), control at {args.rate_hz:g} Hz; folder {out}", file=sys.stderr)
    result = rehearse(args.airframe, profile, out, model=args.model, rate_hz=args.rate_hz,
                      sensors=args.sensors, parameters=dict(args.param), say=LiveLine().log,
                      rt_cpus=args.rt_cpus, reference=args.reference)
    print("\n".join(summary_lines(result)))
    print(f"wrote {out / 'rehearsal.html'}, rehearsal.md, rehearsal.xml, parameters.params")
    if args.junit is not None:
        args.junit.parent.mkdir(parents=True, exist_ok=True)
        write_atomic(args.junit, (out / "rehearsal.xml").read_text())
        print(f"wrote {args.junit}")
    return 0 if result.passed else 1
