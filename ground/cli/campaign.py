"""``ivfm campaign``: many randomized flights on Dask, summarised with statistics."""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

from contracts.arguments import number
from ground.campaign.report import markdown, write_report
from ground.campaign.run import read_rows, run_campaign
from ground.campaign.spec import read_campaign
from ground.cli.common import UsageError

DESCRIPTION = (
    "Fly every draw of a campaign file with every controller it names, on a Dask cluster "
    "(a LocalCluster on this machine unless --scheduler), streaming results into the "
    "folder; a rerun skips finished runs. Writes results.csv, runs/*.json, report.md, "
    "report.json and figures (docs/campaigns.md).")


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("campaign", help="a shipped campaign (ivfm campaigns) or a campaign .toml")
    p.add_argument("--out", type=Path,
                   help="the campaign folder (default runs/NAME; the same folder resumes)")
    p.add_argument("--scheduler", metavar="ADDRESS",
                   help="a running Dask scheduler (tcp://HOST:8786) instead of a "
                        "LocalCluster on this machine")
    p.add_argument("--workers", type=number(1, 1024, integer=True),
                   help="LocalCluster workers (default: one per CPU)")
    p.add_argument("--runs", type=number(1, 100_000, integer=True),
                   help="draws per scenario (default: the file's)")
    p.add_argument("--report-only", action="store_true",
                   help="write the report from the runs in the folder, fly nothing")


def handle(args: argparse.Namespace) -> int:
    campaign = read_campaign(args.campaign)
    if args.runs is not None:
        campaign = dataclasses.replace(campaign, runs=args.runs)
    out = args.out or Path("runs") / campaign.name
    if not args.report_only:
        try:
            counts = run_campaign(campaign, out, scheduler=args.scheduler,
                                  workers=args.workers)
        except KeyboardInterrupt:
            print("ivfm: campaign stopped; its finished runs are in "
                  f"{out}; the same command goes on from there", file=sys.stderr)
            return 130
        print(f"ivfm: {counts['flown']} runs flown ({counts['failed']} failed), "
              f"{counts['skipped']} done before, of {counts['total']}", file=sys.stderr)
    rows = read_rows(out)
    if not rows:
        raise UsageError(f"{out} holds no finished runs")
    report = write_report(out, campaign.name, campaign.kind, campaign.controllers, rows)
    print(markdown(campaign.name, campaign.kind, report))
    print(f"wrote {out / 'report.md'}, report.json, results.csv and figures")
    return 0
