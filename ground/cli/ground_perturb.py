"""``ivfm ground perturb``: a perturbation injected into a running vehicle and
acknowledged (or listed, or cleared)."""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any

from contracts.arguments import TIMEOUT_S, VEHICLE_ID, number
from contracts.perturbations import KINDS
from contracts.telemetry import AUTOPILOT, DEFAULT_GROUND_ENDPOINT, SITL
from contracts.zenoh_link import add_zenoh_arguments, zenoh_options_from_args
from ground.cli.common import UsageError
from ground.uplink.perturb import PerturbationClient, PerturbationError

_KINDS_TEXT = "; ".join(f"{k}: {', '.join(v.params) or '-'} ({v.target})"
                        for k, v in KINDS.items())
DESCRIPTION = (f"Kinds and their NAME=VALUE fields: {_KINDS_TEXT}. "
               "'list' and 'clear' show and end perturbations.")


def add_arguments(pert: argparse.ArgumentParser) -> None:
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


def _perturb_value(text: str) -> Any:
    """A NAME=VALUE right-hand side: a number or comma-separated numbers."""
    parts = [p.strip() for p in text.split(",")]
    try:
        numbers = [float(p) for p in parts]
    except ValueError:
        raise UsageError(f"{text!r} is not a number or a comma-separated list of numbers") \
            from None
    return numbers if len(numbers) > 1 else numbers[0]


def _request(args: argparse.Namespace) -> dict[str, Any]:
    request: dict[str, Any] = {"kind": args.kind, "start_s": args.start}
    if args.start != "now":
        try:
            request["start_s"] = float(args.start)
        except ValueError:
            raise UsageError(f"--start must be 'now' or seconds, got {args.start!r}") from None
    if args.end is not None:
        request["end_s"] = args.end
    if args.duration is not None:
        request["duration_s"] = args.duration
    if args.id is not None:
        request["id"] = args.id
    for item in args.values:
        name, sep, value = item.partition("=")
        if not sep:
            raise UsageError(f"expected NAME=VALUE, got {item!r}; {args.kind} takes "
                             f"{', '.join(KINDS[args.kind].params) or 'nothing'}")
        request[name] = _perturb_value(value)
    return request


def handle(args: argparse.Namespace) -> int:
    with PerturbationClient(zenoh_options_from_args(args), timeout_s=args.timeout) as client:
        try:
            if args.kind in ("list", "clear"):
                targets = [args.target] if args.target else [SITL, AUTOPILOT]
                for target in targets:
                    if args.kind == "list":
                        for entry in client.list(args.vehicle, target):
                            print(f"{target}: {json.dumps(entry)}")
                    else:
                        answer = client.clear(args.vehicle, target, args.id)
                        print(f"{target}: cleared {', '.join(answer['cleared']) or 'nothing'}")
                return 0
            answer = client.send(args.vehicle, _request(args))
        except PerturbationError as exc:
            print(f"ivfm: error: {exc}", file=sys.stderr)
            return 1
    print(f"accepted by vehicle {args.vehicle}: {json.dumps(answer)}")
    return 0
