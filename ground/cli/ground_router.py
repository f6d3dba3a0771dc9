"""``ivfm ground router``: a Zenoh router linking machines, until a signal stops it."""

from __future__ import annotations

import argparse
import sys

from contracts.stop_request import StopRequest
from contracts.telemetry import DEFAULT_PORT
from contracts.zenoh_link import ZenohOptions, add_security_arguments, open_session, tls_from_args

DESCRIPTION = ("Links beyond this machine need certificates (--zenoh-tls) or "
               "--zenoh-insecure (docs/telemetry.md#security).")


def add_arguments(router: argparse.ArgumentParser) -> None:
    router.add_argument("--listen", action="append", metavar="ENDPOINT",
                        help=f"default tls/0.0.0.0:{DEFAULT_PORT} with --zenoh-tls, else "
                             f"tcp/0.0.0.0:{DEFAULT_PORT} (needs --zenoh-insecure); "
                             "repeatable")
    router.add_argument("--connect", action="append", metavar="ENDPOINT",
                        help="other routers (repeatable)")
    add_security_arguments(router, "ground")


def handle(args: argparse.Namespace) -> int:
    tls = tls_from_args(args)
    default = f"{'tls' if tls else 'tcp'}/0.0.0.0:{DEFAULT_PORT}"
    options = ZenohOptions("router", listen=args.listen or [default],
                           connect=args.connect or [], tls=tls, insecure=args.zenoh_insecure)
    session = open_session(options, exit_on_listen_failure=True)
    stop = StopRequest()
    stop.on_signals()
    print(f"ivfm ground router: listening on {', '.join(options.listen)}"
          + (f", linked to {', '.join(options.connect)}" if options.connect else ""),
          file=sys.stderr, flush=True)
    stop.wait(poll_s=0.1)
    session.close()
    return 0
