"""``ivfm ground view``: the telemetry of every vehicle heard over Zenoh, served live to
Foxglove."""

from __future__ import annotations

import argparse

from contracts.telemetry import DEFAULT_GROUND_ENDPOINT
from contracts.zenoh_link import add_zenoh_arguments, zenoh_options_from_args
from ground.telemetry.live_view import (
    DEFAULT_VIEW_PORT,
    add_view_arguments,
    serve_view,
    view_address,
)

DESCRIPTION = ("Serves the telemetry of every vehicle heard over Zenoh to Foxglove (open "
               "connection, Foxglove WebSocket, ws://HOST:PORT; docs/telemetry.md#foxglove). "
               "A slow or absent viewer never slows the vehicles.")


def add_arguments(view: argparse.ArgumentParser) -> None:
    view.add_argument("--view", type=view_address, default=("127.0.0.1", DEFAULT_VIEW_PORT),
                      metavar="[HOST:]PORT",
                      help=f"where to serve it (default 127.0.0.1:{DEFAULT_VIEW_PORT})")
    add_view_arguments(view)
    add_zenoh_arguments(view, [], [DEFAULT_GROUND_ENDPOINT])


def handle(args: argparse.Namespace) -> int:
    return serve_view(zenoh_options_from_args(args), *args.view, rate_hz=args.view_rate_hz)
