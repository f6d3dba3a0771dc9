"""``ivfm compare``: every controller on every scenario and plant, tables and figures."""

from __future__ import annotations

import argparse
from pathlib import Path

from autopilot.control.factory import CONTROLLERS, load_models
from autopilot.parameters import validate_parameters
from ground.campaign.compare import run_comparison
from ground.cli.common import add_vehicle_options, fresh_folder
from ground.scenario.scenario_file import PAPER_SCENARIOS, scenario_by_name
from sitl.dynamics import FIDELITIES


def add_arguments(compare: argparse.ArgumentParser) -> None:
    compare.add_argument("--out", type=Path, default=None,
                         help="the comparison's folder (default: a new one under runs/)")
    compare.add_argument("--scenarios", nargs="+", default=list(PAPER_SCENARIOS))
    compare.add_argument("--controllers", nargs="+", default=list(CONTROLLERS))
    compare.add_argument("--plants", nargs="+", default=list(FIDELITIES))
    add_vehicle_options(compare)


def handle(args: argparse.Namespace) -> int:
    for name in args.scenarios:
        scenario_by_name(name)
    parameters = validate_parameters(dict(args.param))
    models = load_models(args.model, args.airframe, args.any_airframe_model)
    return run_comparison(args.scenarios, args.controllers, args.plants, args.airframe, models,
                          parameters, args.out or fresh_folder("compare"))
