"""The pytest plugin installed with the package (entry point ``pytest11``: ``ivfm``).

* Scenario files with an ``[expect]`` table are test files: ``pytest scenarios/`` flies
  each through the processes once and gives one test item per expectation.
* The ``ivfm_flight`` fixture flies a scenario (a shipped name, a file or a dict of the
  file's tables) and returns its metrics, events and verdicts, for tests of one's own.

docs/checks.md has a worked example. Options: ``--ivfm-out DIR`` keeps the run folders
there (default: pytest's temporary folder), ``--ivfm-realtime`` paces to the wall clock.
Flights of a session share one process loader (docs/checks.md). Nothing heavy is
imported until a scenario flies: every pytest session of the environment loads this
module.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pytest

if TYPE_CHECKING:
    from ground.scenario.expectations import Outcome
    from ground.scenario.scenario_file import Scenario


def pytest_addoption(parser: pytest.Parser) -> None:
    group = parser.getgroup("ivfm", "IVFM-SITL scenario checks")
    group.addoption("--ivfm-out", type=Path, default=None, metavar="DIR",
                    help="keep the run folders of scenario flights here")
    group.addoption("--ivfm-realtime", action="store_true",
                    help="fly scenarios paced to the wall clock (default: lockstep)")


@dataclass
class Flight:
    """A flown scenario: metrics.json's content, the events, the verdicts."""

    scenario: Scenario
    run_dir: Path
    metrics: dict[str, Any]
    outcomes: list[Outcome]

    @property
    def events(self) -> list[dict[str, Any]]:
        return self.metrics.get("events", [])

    @property
    def failures(self) -> list[Outcome]:
        return [o for o in self.outcomes if not o.passed]

    def assert_expectations(self) -> None:
        """AssertionError naming every expectation that failed, measured against limit."""
        if self.failures:
            raise AssertionError(f"{self.scenario.name}: "
                                 + "; ".join(f"{o.name}: {o.message}" for o in self.failures)
                                 + f" (run folder {self.run_dir})")


def _runs_root(config: pytest.Config) -> Path:
    given = config.getoption("ivfm_out")
    if given is not None:
        return Path(given)
    factory = getattr(config, "_tmp_path_factory", None)  # pytest's tmp_path_factory
    if factory is None:
        import tempfile

        return Path(tempfile.mkdtemp(prefix="ivfm-runs-"))
    return factory.mktemp("ivfm-runs")


_LOADER = pytest.StashKey[Any]()


def _process_loader(config: pytest.Config) -> Any:
    """One process loader for the session's flights (contracts/zygote.py)."""
    if _LOADER not in config.stash:
        from ground.run.loader import ProcessLoader

        config.stash[_LOADER] = ProcessLoader()
    return config.stash[_LOADER]


def pytest_unconfigure(config: pytest.Config) -> None:
    if _LOADER in config.stash:
        config.stash[_LOADER].close()


def fly(scenario: Scenario, run_dir: Path, config: pytest.Config,
        **overrides: Any) -> Flight:
    """Fly ``scenario`` through processes forked by the session's loader into ``run_dir``;
    judge it."""
    from ground.run.flights import Overrides, fly_processes, plan_flight
    from ground.scenario.expectations import evaluate

    plan = plan_flight(scenario, Overrides(realtime=config.getoption("ivfm_realtime"),
                                           **overrides))
    metrics = fly_processes(plan, run_dir, figures=False, quiet=True,
                            loader=_process_loader(config))
    return Flight(scenario, run_dir, metrics, evaluate(scenario.expect, metrics))


@pytest.fixture
def ivfm_flight(request: pytest.FixtureRequest,
                tmp_path: Path) -> Callable[..., Flight]:
    """``ivfm_flight(scenario, **overrides)``: fly and return a ``Flight``. ``scenario``:
    a shipped name, a scenario file, or a dict of a scenario file's tables (files it
    names are relative to the test's folder). Overrides: controller, plant, airframe,
    sensors, state_source, parameters, model_path, rate_hz, seed."""
    from ground.scenario.scenario_file import scenario_by_name, scenario_from_dict

    config = request.config
    root = config.getoption("ivfm_out") or tmp_path
    count = [0]

    def run(scenario: str | Path | dict[str, Any], **overrides: Any) -> Flight:
        count[0] += 1
        if isinstance(scenario, dict):
            name = str(scenario.get("name", "scenario"))
            parsed = scenario_from_dict(scenario, tmp_path / f"{name}-{count[0]}.toml",
                                        request.path.parent)
        else:
            parsed = scenario_by_name(str(scenario))
        folder = re.sub(r"[^\w.-]", "_", request.node.name)
        return fly(parsed, Path(root) / f"{folder}-{count[0]}-{parsed.name}", config,
                   **overrides)

    return run


def pytest_collect_file(parent: pytest.Collector, file_path: Path) -> pytest.File | None:
    """A ``.toml`` with a scenario's tables and an ``[expect]`` table is a test file."""
    if file_path.suffix != ".toml":
        return None
    import tomllib

    try:
        data = tomllib.loads(file_path.read_text())
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError):
        return None
    if "expect" not in data or not ("reference" in data or "mission" in data):
        return None
    return ScenarioFile.from_parent(parent, path=file_path)


class ScenarioFile(pytest.File):
    """One scenario file: one flight, one item per expectation."""

    def collect(self) -> Iterator[pytest.Item]:
        from ground.scenario.scenario_file import load_scenario

        self.scenario = load_scenario(self.path)  # a bad file is a collection error
        self._flight: Flight | None = None
        self._error: BaseException | None = None
        for index, name in enumerate(self.scenario.expect.names()):
            yield ExpectationItem.from_parent(self, name=name, index=index)

    def flight(self) -> Flight:
        """Flown once, on the first item's turn."""
        if self._flight is None and self._error is None:
            run_dir = _runs_root(self.config) / self.scenario.name
            try:
                self._flight = fly(self.scenario, run_dir, self.config)
            except Exception as exc:  # every item of the file reports it
                self._error = exc
        if self._error is not None:
            raise ScenarioFlightError(f"the flight of {self.scenario.name} failed: "
                                      f"{self._error}")
        assert self._flight is not None
        return self._flight


class ScenarioFlightError(Exception):
    """The scenario did not fly (a process failed)."""


class ExpectationError(AssertionError):
    """An expectation did not hold."""


class ExpectationItem(pytest.Item):
    def __init__(self, *, index: int, **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self.index = index

    def runtest(self) -> None:
        flight = self.parent.flight()  # type: ignore[attr-defined]
        outcome = flight.outcomes[self.index]
        if not outcome.passed:
            raise ExpectationError(f"{outcome.message}\nrun folder: {flight.run_dir} "
                                    f"(ivfm report {flight.run_dir})")

    def repr_failure(self, excinfo: pytest.ExceptionInfo[BaseException],
                     style: Any = None) -> str:
        if isinstance(excinfo.value, (ExpectationError, ScenarioFlightError)):
            return str(excinfo.value)
        return super().repr_failure(excinfo)

    def reportinfo(self) -> tuple[Path, int | None, str]:
        return self.path, None, f"{self.parent.name}::{self.name}"
