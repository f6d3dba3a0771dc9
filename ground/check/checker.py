"""``ivfm check``: fly scenario files and judge them by their expectations.

Each scenario flies through the processes (lockstep unless ``--realtime``) into its own
run folder; its ``[expect]`` table gives one verdict per expectation. Results go to a
table on the terminal, and if asked to a JUnit XML file (one testsuite per scenario, one
testcase per expectation) and a Markdown summary (GitHub's job summary). A baseline (an
earlier check's ``check.json``) catches drift of the metrics. Run folders of failed
scenarios are kept, so ``ivfm report`` can open them again. docs/checks.md is the guide.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import threading
import time
from collections.abc import Callable, Iterable
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ground.record.run_files import write_json
from ground.run.flights import Overrides, fly_processes, plan_flight
from ground.run.loader import ProcessLoader, ProcessRunError, take_loader
from ground.run.placement import FlightSlot, FlightSlots
from ground.run.progress import LiveLine
from ground.scenario.expectations import Outcome, evaluate
from ground.scenario.scenario_file import Scenario, load_scenario, scenario_by_name, shipped_names

RESULTS_FILE = "check.json"
DEFAULT_TOLERANCE = 0.05
# The metrics a baseline compares (wall-clock figures drift with the machine: not these).
BASELINE_SECTIONS = ("axes", "estimation", "path", "control")
BASELINE_SKIPPED = frozenset({"mse", "chattering_total_variation", "arrival_s", "items",
                              "all_reached"})
ABSOLUTE_FLOOR = 1e-9  # changes smaller than this are rounding, whatever the ratio


@dataclass
class ScenarioResult:
    """One scenario's check: its verdicts, or the error that stopped its flight."""

    scenario: Scenario
    run_dir: Path
    outcomes: list[Outcome] = field(default_factory=list)
    wall_time_s: float = 0.0
    metrics: dict[str, Any] | None = None
    error: str | None = None

    @property
    def passed(self) -> bool:
        return self.error is None and all(o.passed for o in self.outcomes)

    @property
    def failures(self) -> list[Outcome]:
        return [o for o in self.outcomes if not o.passed]

    @property
    def label(self) -> str:
        return "PASS" if self.passed else "ERROR" if self.error else "FAIL"


def collect(paths: Iterable[str]) -> list[Scenario]:
    """The scenario files named (shipped names, files or folders of ``*.toml``, folders
    searched recursively), each parsed and checked; ValueError on anything wrong."""
    paths = list(paths) or shipped_names()
    scenarios: list[Scenario] = []
    for given in paths:
        path = Path(given)
        if path.is_dir():
            files = sorted(path.rglob("*.toml"))
            found = [load_scenario(f) for f in files if _is_scenario_file(f)]
            if not found:
                raise ValueError(f"{path} holds no scenario file")
            scenarios += found
        elif path.exists():
            scenarios.append(load_scenario(path))
        else:
            scenarios.append(scenario_by_name(given))
    names = [s.name for s in scenarios]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise ValueError(f"scenario name(s) given twice: {', '.join(twice)} (the name is the "
                         f"run folder's; rename one with name = ...)")
    return scenarios


def _is_scenario_file(path: Path) -> bool:
    """A scenario, not an airframe, sensor profile or project file beside one."""
    import tomllib

    try:
        data = tomllib.loads(path.read_text())
    except (OSError, tomllib.TOMLDecodeError):
        return True  # load_scenario says what is wrong with it
    return "reference" in data or "mission" in data


def read_baseline(path: Path) -> dict[str, dict[str, Any]]:
    """An earlier check's metrics by scenario (its folder or its check.json)."""
    file = path / RESULTS_FILE if path.is_dir() else path
    try:
        data = json.loads(file.read_text())
        return {name: entry["metrics"] for name, entry in data["scenarios"].items()
                if entry.get("metrics") is not None}
    except OSError as exc:
        raise ValueError(f"--baseline: cannot read {file}: {exc.strerror}") from None
    except (ValueError, KeyError, TypeError, AttributeError):
        raise ValueError(f"--baseline: {file} is not a {RESULTS_FILE} written by ivfm "
                         f"check") from None


def baseline_numbers(metrics: dict[str, Any]) -> dict[str, float]:
    """The metrics a baseline compares, flattened to dotted names."""
    out: dict[str, float] = {}

    def walk(prefix: str, value: Any) -> None:
        if isinstance(value, dict):
            for key, inner in value.items():
                if key not in BASELINE_SKIPPED:
                    walk(f"{prefix}.{key}" if prefix else key, inner)
        elif isinstance(value, (int, float)) and not isinstance(value, bool) and \
                math.isfinite(value):
            out[prefix] = float(value)

    for section in BASELINE_SECTIONS:
        if section in metrics:
            walk(section, metrics[section])
    return out


def compare_baseline(metrics: dict[str, Any], baseline: dict[str, Any] | None,
                     tolerance: float) -> Outcome:
    """One verdict: every compared metric within ``tolerance`` (relative) of the
    baseline's. A lockstep run repeats bit for bit, so any change is the code's."""
    name = f"baseline: metrics within {100 * tolerance:g} % of the baseline"
    if baseline is None:
        return Outcome(name, False, None, tolerance, "the baseline has no run of this "
                       "scenario")
    now, then = baseline_numbers(metrics), baseline_numbers(baseline)
    drifted = []
    for key in sorted(set(now) | set(then)):
        if key not in now or key not in then:
            drifted.append(f"{key}: {'new' if key in now else 'gone'}")
            continue
        change = abs(now[key] - then[key])
        if change > ABSOLUTE_FLOOR and change > tolerance * abs(then[key]):
            ratio = (now[key] - then[key]) / abs(then[key]) if then[key] else math.inf
            drifted.append(f"{key}: {now[key]:.6g} against {then[key]:.6g} "
                           f"({100 * ratio:+.1f} %)")
    worst = max((abs(now[k] - then[k]) / abs(then[k]) for k in now
                 if k in then and then[k] and abs(now[k] - then[k]) > ABSOLUTE_FLOOR),
                default=0.0)
    return Outcome(name, not drifted, worst, tolerance,
                   "every metric within tolerance" if not drifted else
                   f"{len(drifted)} metric(s) moved beyond {100 * tolerance:g} %: "
                   + "; ".join(drifted[:8]) + (" ..." if len(drifted) > 8 else ""))


@dataclass(frozen=True)
class CheckOptions:
    out_dir: Path
    realtime: bool = False
    jobs: int = 1
    baseline: dict[str, dict[str, Any]] | None = None
    tolerance: float = DEFAULT_TOLERANCE
    keep_passed: bool = False
    forked: bool = True  # every run's processes forked by one process loader
    figures: bool | str = False  # each run folder's figures (run_report.report's figures=)
    figures_on_failure: bool = False  # a failed run's every figure and its page
    rt_cpus: frozenset[int] | None = None  # the vehicle processes' CPUs (None: any)


def check_one(scenario: Scenario, options: CheckOptions,
              loader: ProcessLoader | None = None,
              overrides: Overrides | None = None,
              started_s: float | None = None,
              flight_slot: FlightSlot | None = None) -> ScenarioResult:
    """Fly one scenario (its processes forked by ``loader``, if given; with ``overrides`` of
    its choices, else only ``options.realtime``) and judge it; a failed flight is a
    result, not an exception. ``started_s`` (time.monotonic): the origin of the run's
    timeline (default: when the processes start), so a caller can place its marks;
    ``flight_slot``: held while it flies."""

    run_dir = options.out_dir / scenario.name
    result = ScenarioResult(scenario, run_dir)
    start = time.perf_counter()
    try:
        plan = plan_flight(scenario, overrides or Overrides(realtime=options.realtime,
                                                            rt_cpus=options.rt_cpus))
        result.metrics = fly_processes(plan, run_dir, figures=options.figures, quiet=True,
                                       loader=loader, started_s=started_s,
                                       flight_slot=flight_slot)
    except (ProcessRunError, ValueError, OSError) as exc:
        result.error = str(exc)
    result.wall_time_s = time.perf_counter() - start
    if result.metrics is not None:
        result.outcomes = evaluate(scenario.expect, result.metrics)
        if options.baseline is not None:
            result.outcomes.append(compare_baseline(
                result.metrics, options.baseline.get(scenario.name), options.tolerance))
        if options.figures_on_failure and options.figures is not True and not result.passed:
            from ground.report.run_report import report  # loaded during the flight

            report(run_dir, figures=True)  # from the log again: only for a failure
    if result.passed and not options.keep_passed:
        shutil.rmtree(run_dir, ignore_errors=True)
    return result


def flights_at_once(jobs: int) -> int:
    """How many of a lockstep check's ``jobs`` runs in progress fly at once: one per usable
    CPU (each flight's two loops take turns on a CPU of its own, its logger and the
    others' start-up share the rest). The runs past that start their processes and wait,
    or write their reports, meanwhile."""
    return max(1, min(jobs, len(os.sched_getaffinity(0))))


def run_check(scenarios: list[Scenario], options: CheckOptions,
              progress: Callable[[ScenarioResult, int, list[str]], None] | None = None
              ) -> list[ScenarioResult]:
    """Check every scenario, ``options.jobs`` at a time; results in the given order.
    ``progress`` hears each result as it comes, with the count done and what still flies."""
    options.out_dir.mkdir(parents=True, exist_ok=True)

    flying: list[str] = []
    lock = threading.Lock()
    done: dict[str, ScenarioResult] = {}
    loader = take_loader() if options.forked else None
    # Real time: no places (a paced run keeps its own isolation: --rt-cpus, ivfm shield).
    slots = FlightSlots(flights_at_once(options.jobs)) if not options.realtime else None

    def job(scenario: Scenario) -> ScenarioResult:
        with lock:
            flying.append(scenario.name)
        try:
            if slots is None:
                return check_one(scenario, options, loader)
            with slots.assign() as slot:
                return check_one(scenario, options, loader, flight_slot=slot)
        finally:
            with lock:
                flying.remove(scenario.name)

    try:
        with ThreadPoolExecutor(max_workers=max(1, options.jobs)) as pool:
            futures = [pool.submit(job, s) for s in scenarios]
            for future in as_completed(futures):
                result = future.result()
                done[result.scenario.name] = result
                if progress is not None:
                    with lock:
                        progress(result, len(done), list(flying))
    finally:
        if slots is not None:
            slots.close()
        if loader is not None:
            loader.close()
    results = [done[s.name] for s in scenarios]
    write_results(results, options.out_dir / RESULTS_FILE)
    return results


def write_results(results: list[ScenarioResult], path: Path) -> None:
    """check.json: each scenario's verdicts and metrics (an input to --baseline)."""

    write_json(path, {"scenarios": {r.scenario.name: {
        "passed": r.passed, "error": r.error, "run_dir": str(r.run_dir) if not r.passed else None,
        "wall_time_s": r.wall_time_s, "source": str(r.scenario.source),
        "outcomes": [{"name": o.name, "passed": o.passed, "message": o.message,
                      "measured": _json_value(o.measured), "limit": _json_value(o.limit)}
                     for o in r.outcomes],
        "metrics": r.metrics} for r in results}})


def _json_value(value: Any) -> Any:
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


# -- reports --------------------------------------------------------------------------------

class Progress:
    """A live line on a terminal; one line per finished scenario elsewhere (CI logs)."""

    def __init__(self, total: int, stream: Any = None) -> None:
        self.total = total
        self.line = LiveLine(stream)
        self.start = time.perf_counter()

    def __call__(self, result: ScenarioResult, done: int, flying: list[str]) -> None:
        elapsed = time.perf_counter() - self.start
        line = (f"[{done}/{self.total}] {result.scenario.name}: {result.label} "
                f"({sum(o.passed for o in result.outcomes)}/{len(result.outcomes)} held, "
                f"{result.wall_time_s:.1f} s)")
        if not self.line.live or done == self.total:
            self.line.log(line)
        else:
            flying_now = f"; flying {', '.join(flying)}" if flying else ""
            self.line.draw(f"{line}{flying_now} [{elapsed:.0f} s]")
