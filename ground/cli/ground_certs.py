"""``ivfm ground certs``: test certificates for mutual TLS on the Zenoh links."""

from __future__ import annotations

import argparse
from pathlib import Path

from ground.telemetry.certificates import DEFAULT_HOSTS, DEFAULT_NAMES, make_certificates

DESCRIPTION = ("A certificate authority and one certificate per --name (default: ground and "
               "vehicle), for --zenoh-tls. Test certificates: a fleet's come from its own "
               "authority.")


def add_arguments(certs: argparse.ArgumentParser) -> None:
    certs.add_argument("--out", type=Path, required=True, help="folder to write them to")
    certs.add_argument("--name", action="append", metavar="NAME",
                       help="an identity (repeatable; default: ground, vehicle)")
    certs.add_argument("--host", action="append", metavar="HOST",
                       help="a name or address the peers reach each other at (repeatable; "
                            "default: localhost, 127.0.0.1)")


def handle(args: argparse.Namespace) -> int:
    names = tuple(args.name or DEFAULT_NAMES)
    written = make_certificates(args.out, names, tuple(args.host or DEFAULT_HOSTS))
    print(f"wrote {len(written)} files to {args.out}: the authority ca.pem and, for "
          + ", ".join(names) + ", NAME.pem and NAME-key.pem. Give each process "
          f"--zenoh-tls {args.out} --zenoh-identity NAME; keep ca-key.pem away from the "
          "vehicles.")
    return 0
