"""``ivfm airframe from-ulog FLIGHT.ulg --mass-kg M --out draft.toml``: a draft airframe
file from a PX4 log."""

from __future__ import annotations

import argparse
from pathlib import Path

from contracts.arguments import number
from contracts.atomic_file import write_atomic
from ground.cli.common import UsageError
from ground.ulog.airframe_draft import draft_airframe

DESCRIPTION = (
    "Write an airframe file from a PX4 log's control allocation (CA_ROTOR_COUNT, "
    "CA_ROTORn_PX/PY/PZ, CA_ROTORn_KM: rotor positions, spin directions, moment ratios), "
    "thrust model (THR_MDL_FAC) and hover thrust, with every number the log does not hold "
    "marked TO_FILL for you to fill in; every command refuses the file until none is left "
    "(docs/px4-logs.md). A log of a vehicle this stack cannot fly (not a quadrotor, a "
    "tilted rotor) is refused, saying why.")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("file", type=Path, help="the PX4 log (.ulg)")
    p.add_argument("--mass-kg", type=number(1e-3, 1e3, "kg"), required=True,
                   help="the vehicle's take-off mass (weighed; not in a PX4 log)")
    p.add_argument("--max-rad-s", type=number(0.0, 1e5, "rad/s", low_open=True),
                   help="the rotors' top speed (motor KV x battery volts x 2 pi / 60; "
                        "default: fitted to ESC rpm telemetry when logged, else TO_FILL)")
    p.add_argument("--name", help="the airframe's name (default: the file name of --out)")
    p.add_argument("--out", type=Path, required=True, help="the airframe .toml to write")
    p.add_argument("--force", action="store_true", help="overwrite --out if it exists")


def handle(args: argparse.Namespace) -> int:
    if args.out.suffix != ".toml":
        raise UsageError(f"--out must name a .toml file, got {args.out}")
    if args.out.exists() and not args.force:
        raise UsageError(f"{args.out} exists (a filled-in airframe?): give another --out, "
                         "or --force")
    name = args.name or args.out.stem
    draft = draft_airframe(args.file, args.mass_kg, args.max_rad_s, name)
    write_atomic(args.out, draft.text)
    print(f"wrote {args.out}")
    if draft.to_fill:
        print(f"fill in (marked TO_FILL): {', '.join(draft.to_fill)}")
    if draft.assumed:
        print(f"check (ASSUMED, not in the log): {', '.join(draft.assumed)}")
    return 0
