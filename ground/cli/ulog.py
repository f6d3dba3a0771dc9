"""``ivfm ulog ...``: PX4 flight logs (ULog) in (docs/px4-logs.md)."""

from __future__ import annotations

from ground.cli.registry import Subcommand

SUBCOMMANDS = (
    Subcommand("info", "ground.cli.ulog_info",
               "what a PX4 log holds for identification and a draft airframe"),
)
