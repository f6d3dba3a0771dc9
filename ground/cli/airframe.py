"""``ivfm airframe ...``: airframe files (docs/airframes.md)."""

from __future__ import annotations

from ground.cli.registry import Subcommand

SUBCOMMANDS = (
    Subcommand("from-ulog", "ground.cli.airframe_from_ulog",
               "a draft airframe file from a PX4 log (docs/px4-logs.md)"),
)
