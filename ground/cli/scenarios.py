"""``ivfm scenarios``: the shipped scenarios, one line each."""

from __future__ import annotations

import argparse

from ground.scenario.scenario_file import shipped_scenarios


def add_arguments(_p: argparse.ArgumentParser) -> None:
    pass


def handle(args: argparse.Namespace) -> int:
    for s in shipped_scenarios().values():
        kicks = f", {len(s.perturbations)} perturbations" if s.perturbations else ""
        print(f"{s.name:<16} {s.description} (judged on {', '.join(s.axes)} after "
              f"{s.transient_s:g} s{kicks}; {s.source})")
    return 0
