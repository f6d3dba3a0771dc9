"""``ivfm report``: metrics.json, figures and the run's page again, from its log alone."""

from __future__ import annotations

import argparse
from pathlib import Path

from ground.report.metrics import format_metrics
from ground.report.run_report import report


def add_arguments(rep: argparse.ArgumentParser) -> None:
    rep.add_argument("run_dir", type=Path, help="a folder written by ivfm run")
    rep.add_argument("--no-figures", action="store_true")


def handle(args: argparse.Namespace) -> int:
    metrics, record = report(args.run_dir, figures=not args.no_figures)
    print(format_metrics(metrics))
    print(f"wrote {args.run_dir / 'metrics.json'}" + ("" if args.no_figures else " and figures"))
    return 1 if record.diverged else 0
