"""Zenoh sessions and the processes' telemetry node (docs/architecture.md).

Sessions are peers on explicit loopback endpoints by default: the ground station (logger)
listens on ``tcp/127.0.0.1:7447`` and vehicles connect there, retrying quietly while it is
away; multicast scouting is off, gossip lets peers find each other through whoever they
reach. ``client`` mode goes through a router only (``ivfm ground router``).

The processes' node on a session (publishers, batches, requests, status) is
``contracts/telemetry_node.py``.
"""

from __future__ import annotations

import argparse
import json
import re
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import zenoh

from contracts.arguments import number
from contracts.telemetry import DEFAULT_GROUND_ENDPOINT

MODES = ("peer", "client", "router")
DEFAULT_BATCH_S = 0.02  # the live view's lag in real time, at most (and one step)
# In lockstep nothing waits on a record but the logger, and each put costs both sides
# (docs/telemetry.md, Batches): five times fewer puts, and at 20x a batch a 5 ms lag.
LOCKSTEP_BATCH_S = 0.1
MAX_BATCH_S = 1.0
_ENDPOINT = re.compile(r"^(tcp|udp|tls|quic|ws)/(\[[0-9a-fA-F:]+\]|[A-Za-z0-9.\-]+):\d{1,5}$")


@dataclass(frozen=True)
class TlsIdentity:
    """Mutual TLS: the authority every peer's certificate must be signed by, and this
    process's own certificate and key. The certificate's common name is the identity
    the vehicles' access control reads."""

    ca: Path
    cert: Path
    key: Path

    @classmethod
    def from_folder(cls, folder: Path, name: str) -> TlsIdentity:
        """``ca.pem``, ``NAME.pem`` and ``NAME-key.pem`` in ``folder`` (as ``ivfm ground
        certs`` writes them)."""
        identity = cls(folder / "ca.pem", folder / f"{name}.pem", folder / f"{name}-key.pem")
        for path in (identity.ca, identity.cert, identity.key):
            if not path.is_file():
                raise ValueError(f"--zenoh-tls: {path} is missing (a folder with ca.pem, "
                                 f"{name}.pem and {name}-key.pem; test ones: ivfm ground "
                                 "certs --out FOLDER)")
        return identity


LOOPBACK_HOSTS = ("localhost", "[::1]", "::1")
CLEAR_PROTOCOLS = ("tcp", "udp", "ws")  # tls and quic are encrypted


def is_loopback(endpoint: str) -> bool:
    host = endpoint.split("/", 1)[1].rsplit(":", 1)[0]
    return host in LOOPBACK_HOSTS or host.startswith("127.")


# Who may query a vehicle's services (perturb, start) when its links are certified: the
# certificate common names of the ground station (ivfm ground certs makes "ground").
DEFAULT_COMMANDERS = ("ground",)


@dataclass
class ZenohOptions:
    mode: str = "peer"
    listen: list[str] = field(default_factory=list)
    connect: list[str] = field(default_factory=list)
    enabled: bool = True
    tls: TlsIdentity | None = None
    # With ``tls``: only peers whose certificate names one of these may query this
    # session (a vehicle's services); None: no access control (a ground process).
    commanders: tuple[str, ...] | None = None
    insecure: bool = False  # allow clear-text links beyond this machine
    # False: open returns at once and connects in the background, retrying every 20 ms
    # at first (a ground station's querying session, whose peers may not be up yet);
    # True: open waits (up to OPEN_WAIT_MS) for the endpoints, so the first records have a
    # route.
    wait_on_open: bool = True
    # A vehicle process sends its records in one batch per this much sim time (0: each
    # on its own): docs/telemetry.md, "Batches".
    batch_s: float = DEFAULT_BATCH_S

    def __post_init__(self) -> None:
        if not (isinstance(self.batch_s, (int, float)) and 0.0 <= self.batch_s <= MAX_BATCH_S):
            # (NaN fails the comparison too)
            raise ValueError(f"telemetry batch span must be in [0, {1e3 * MAX_BATCH_S:g}] ms, "
                             f"got {self.batch_s!r} s")
        if self.mode not in MODES:
            raise ValueError(f"zenoh mode must be one of {', '.join(MODES)}, got {self.mode!r}")
        for endpoint in [*self.listen, *self.connect]:
            check_endpoint(endpoint)
            protocol = endpoint.split("/", 1)[0]
            if protocol not in CLEAR_PROTOCOLS and self.tls is None:
                raise ValueError(f"{endpoint}: {protocol} needs certificates: --zenoh-tls "
                                 "FOLDER (test ones: ivfm ground certs --out FOLDER)")
            if protocol in CLEAR_PROTOCOLS and not is_loopback(endpoint) and not self.insecure:
                host_port = endpoint.split("/", 1)[1]
                raise ValueError(
                    f"{endpoint} reaches beyond this machine in clear text, where anyone "
                    f"on the network could command the vehicle: use tls/{host_port} with "
                    "--zenoh-tls FOLDER (test certificates: ivfm ground certs --out FOLDER), "
                    "or --zenoh-insecure on a network you trust")
        if self.mode == "client" and self.listen:
            raise ValueError("a zenoh client does not listen; drop --zenoh-listen")


def check_endpoint(endpoint: str) -> str:
    match = _ENDPOINT.match(endpoint)
    if not match or not 0 <= int(endpoint.rsplit(":", 1)[1]) <= 65535:
        raise ValueError(f"zenoh endpoint must look like tcp/127.0.0.1:7447, got {endpoint!r}")
    return endpoint


def add_zenoh_arguments(parser: argparse.ArgumentParser, listen: list[str],
                        connect: list[str], identity: str = "ground",
                        vehicle: bool = False) -> None:
    """The Zenoh options of a command; ``vehicle``: a process that serves requests, whose
    commanders (--zenoh-commander) the access control admits."""
    g = parser.add_argument_group("zenoh")
    g.add_argument("--zenoh-mode", default="peer", choices=["peer", "client"],
                   help="peer (default) or client (through a router only)")
    g.add_argument("--zenoh-listen", action="append", metavar="ENDPOINT",
                   help=f"endpoint to listen on (repeatable; 'none' for none; "
                        f"default {' '.join(listen) or 'none'})")
    g.add_argument("--zenoh-connect", action="append", metavar="ENDPOINT",
                   help=f"endpoint to connect to (repeatable; 'none' for none; "
                        f"default {' '.join(connect) or 'none'})")
    g.add_argument("--no-zenoh", action="store_true", help="no telemetry, no requests")
    add_security_arguments(g, identity)
    if vehicle:
        g.add_argument("--telemetry-batch-ms", type=number(0.0, 1e3 * MAX_BATCH_S, "ms"),
                       metavar="MS",
                       help="send the records of this much sim time in one put (default "
                            f"{1e3 * DEFAULT_BATCH_S:g} in real time, "
                            f"{1e3 * LOCKSTEP_BATCH_S:g} in lockstep; 0: each record on its "
                            "own; in real time, the most a live view lags)")
        g.add_argument("--zenoh-commander", action="append", metavar="NAME",
                       help="with --zenoh-tls: a certificate name that may send requests "
                            "(perturbations, start); repeatable; default "
                            + " ".join(DEFAULT_COMMANDERS))
    parser.set_defaults(_zenoh_listen_default=listen, _zenoh_connect_default=connect)


def add_security_arguments(group: Any, identity: str) -> None:
    """--zenoh-tls, --zenoh-identity, --zenoh-insecure (every Zenoh command, the router's
    too)."""
    group.add_argument("--zenoh-tls", type=Path, metavar="FOLDER",
                       help="mutual TLS: FOLDER holds ca.pem, IDENTITY.pem and "
                            "IDENTITY-key.pem (test ones: ivfm ground certs); needed for "
                            "tls/ endpoints")
    group.add_argument("--zenoh-identity", default=identity, metavar="NAME",
                       help=f"whose certificate in --zenoh-tls is this process's (default "
                            f"{identity})")
    group.add_argument("--zenoh-insecure", action="store_true",
                       help="allow clear-text tcp/udp endpoints beyond this machine")


def tls_from_args(args: argparse.Namespace) -> TlsIdentity | None:
    return (TlsIdentity.from_folder(args.zenoh_tls, args.zenoh_identity)
            if args.zenoh_tls is not None else None)


def zenoh_options_from_args(args: argparse.Namespace) -> ZenohOptions:
    def pick(given: list[str] | None, default: list[str]) -> list[str]:
        values = default if given is None else given
        return [] if values == ["none"] else [v for v in values if v != "none"]

    listen = pick(args.zenoh_listen, args._zenoh_listen_default)
    if args.zenoh_mode == "client" and args.zenoh_listen is None:
        listen = []
    tls = tls_from_args(args)
    commanders = None
    if hasattr(args, "zenoh_commander"):
        commanders = tuple(args.zenoh_commander or DEFAULT_COMMANDERS)
    batch_ms = getattr(args, "telemetry_batch_ms", None)
    if batch_ms is None:
        batch_ms = 1e3 * (LOCKSTEP_BATCH_S if getattr(args, "lockstep", False)
                          else DEFAULT_BATCH_S)
    return ZenohOptions(args.zenoh_mode, listen,
                        pick(args.zenoh_connect, args._zenoh_connect_default),
                        enabled=not args.no_zenoh, tls=tls, commanders=commanders,
                        insecure=args.zenoh_insecure, batch_s=batch_ms / 1e3)


VEHICLE_LISTEN = ["tcp/127.0.0.1:0"]
VEHICLE_CONNECT = [DEFAULT_GROUND_ENDPOINT]


OPEN_WAIT_MS = 100
TX_QUEUE_BATCHES = 16  # of up to 64 KiB: about 3 s of one vehicle's telemetry
WAIT_BEFORE_DROP_US = 20


def session_config(options: ZenohOptions, exit_on_listen_failure: bool = False) -> zenoh.Config:
    config = zenoh.Config()
    config.insert_json5("mode", json.dumps(options.mode))
    config.insert_json5("listen/endpoints", json.dumps(options.listen))
    config.insert_json5("connect/endpoints", json.dumps(options.connect))
    config.insert_json5("listen/exit_on_failure", json.dumps(exit_on_listen_failure))
    config.insert_json5("connect/exit_on_failure", "false")
    # Reconnect quickly when the other side comes (back): ground stations start late. A
    # session that does not wait on open (a run's own, while its logger starts) keeps
    # trying every 20-50 ms: backing off to a second, it met a logger that took 2 s to
    # start up to 0.7 s after it listened.
    config.insert_json5("connect/retry", json.dumps(
        {"period_init_ms": 200 if options.wait_on_open else 20,
         "period_max_ms": 1000 if options.wait_on_open else 50,
         "period_increase_factor": 1.5}))
    # How long open waits for its endpoints and the peers gossip tells it of. Zenoh's
    # 0.5 s made every other warm run wait for a peer of the run before (gone); a
    # loopback connect takes about 3 ms. Open must still wait: one that returns before
    # the link is up loses its first records (measured: every first put lost).
    config.insert_json5("scouting/delay", str(OPEN_WAIT_MS if options.wait_on_open else 0))
    config.insert_json5("scouting/multicast/enabled", "false")
    # A put into a full transmit queue waits up to wait_before_drop before dropping; at
    # Zenoh's default (1 ms, 2 batches) a subscriber that stalls for a moment would make
    # each of a control step's puts wait a millisecond: deadline misses. A deeper queue
    # absorbs the stall instead, and a full one drops at once (counted as lost records).
    config.insert_json5("transport/link/tx/queue/size/data", str(TX_QUEUE_BATCHES))
    config.insert_json5("transport/link/tx/queue/congestion_control/drop/wait_before_drop",
                        str(WAIT_BEFORE_DROP_US))
    if options.tls is not None:
        tls = options.tls
        config.insert_json5("transport/link/tls", json.dumps({
            "root_ca_certificate": str(tls.ca), "enable_mtls": True,
            "listen_certificate": str(tls.cert), "listen_private_key": str(tls.key),
            "connect_certificate": str(tls.cert), "connect_private_key": str(tls.key)}))
        if options.commanders is not None:
            config.insert_json5("access_control", json.dumps(access_control(
                options.commanders)))
    return config


# What every peer may do with a vehicle: all but query its services.
_TELEMETRY_MESSAGES = ["put", "delete", "declare_subscriber", "declare_queryable", "reply",
                       "liveliness_token", "declare_liveliness_subscriber",
                       "liveliness_query"]


def access_control(commanders: tuple[str, ...]) -> dict[str, Any]:
    """Zenoh access control of a vehicle: telemetry for every peer, queries (the
    perturbation and start services) only from the ``commanders``' certificates; a query
    from anyone else is dropped before it reaches the process."""
    return {
        "enabled": True, "default_permission": "deny",
        "rules": [
            {"id": "telemetry", "messages": _TELEMETRY_MESSAGES,
             "flows": ["egress", "ingress"], "permission": "allow", "key_exprs": ["**"]},
            {"id": "requests", "messages": ["query"], "flows": ["egress", "ingress"],
             "permission": "allow", "key_exprs": ["**"]},
        ],
        "subjects": [{"id": "anyone"},
                     {"id": "commanders", "cert_common_names": list(commanders)}],
        "policies": [{"rules": ["telemetry"], "subjects": ["anyone"]},
                     {"rules": ["requests"], "subjects": ["commanders"]}],
    }


CLIENT_CONNECT_TIMEOUT_S = 15.0


def open_session(options: ZenohOptions, exit_on_listen_failure: bool = False) -> zenoh.Session:
    """Open a session; a bad configuration or a taken port gives a ValueError that says so.
    A client needs its router at once, so it retries for a while (a router may be starting)."""
    deadline = time.monotonic() + (CLIENT_CONNECT_TIMEOUT_S if options.mode == "client" else 0)
    while True:
        try:
            return zenoh.open(session_config(options, exit_on_listen_failure))
        except zenoh.ZError as exc:
            if time.monotonic() < deadline:
                time.sleep(0.2)
                continue
            raise ValueError(f"cannot open a zenoh session (listen {options.listen}, connect "
                             f"{options.connect}): {exc}") from None
