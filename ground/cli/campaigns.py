"""``ivfm campaigns``: the shipped campaign files, one line each."""

from __future__ import annotations

import argparse

from ground.campaign.spec import read_campaign, shipped_campaigns


def add_arguments(_p: argparse.ArgumentParser) -> None:
    pass


def handle(args: argparse.Namespace) -> int:
    for name in shipped_campaigns():
        c = read_campaign(name)
        print(f"{c.name:<22} {c.description} ({c.tasks} runs; {c.source})")
    return 0
