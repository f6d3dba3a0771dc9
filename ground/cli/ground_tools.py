"""``ivfm ground ...``: the ground station's own processes and tools, one module each."""

from __future__ import annotations

from ground.cli.registry import Subcommand

SUBCOMMANDS = (
    Subcommand("log", "ground.cli.ground_log", "record all telemetry to MCAP (docs/telemetry.md)"),
    Subcommand("view", "ground.cli.ground_view", "the flight live in Foxglove (WebSocket)"),
    Subcommand("perturb", "ground.cli.ground_perturb", "inject a perturbation (acknowledged)"),
    Subcommand("router", "ground.cli.ground_router", "a Zenoh router linking machines"),
    Subcommand("certs", "ground.cli.ground_certs", "make test certificates for mutual TLS"),
    Subcommand("tlog", "ground.cli.ground_tlog",
               "export the MAVLink mirror of a log as a .tlog"),
    Subcommand("ulog", "ground.cli.ground_ulog",
               "write a run's log as a PX4 flight log (.ulg)"),
)
