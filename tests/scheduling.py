"""The process tier's longest flights first (``pytest -n 6 --longest-first``).

The tier is a hundred tests from a tenth of a second to a minute long, most of them
flights that wait on the wall clock. pytest-xdist hands each worker a contiguous slice of
the collection, so a worker whose slice ends with the two longest flights ran for 40 s
after the other five were done (292 s against 244 s of tests per worker). This scheduler
is the classic longest-processing-time-first rule: tests go out longest first, one at a
time, to whichever worker has room, by the durations recorded in
``tests/process_durations.json`` (a test it does not know counts as ``UNKNOWN_S``).

Tests that share a fixed resource (``ONE_AT_A_TIME``: MAVSDK's own examples, on UDP port
14540) wait for each other on a lock wherever they run; sent out together they would
hold two workers while one waits (23 s in one run). The scheduler sends one of them only
when no other is queued or running, and the next longest test meanwhile.

``--record-durations`` writes what a run measured (setup, call and teardown of each test)
into that file, keeping the entries of tests it did not run. Re-record after adding long
tests: ``python -m pytest -m "process and not alone" -n 6 --longest-first
--record-durations``.
"""

from __future__ import annotations

import json
from collections import defaultdict
from pathlib import Path

import pytest

DURATIONS_FILE = Path(__file__).with_name("process_durations.json")
UNKNOWN_S = 8.0  # about the median process test
QUEUED_PER_WORKER = 2  # the running test and the next: a worker needs both to run the first
# Test files whose tests take turns on one resource (the api_port_14540 fixture's lock,
# tests/groundtools/conftest.py, which checks that its users are listed here).
ONE_AT_A_TIME = ("tests/groundtools/test_mavsdk_examples.py::",
                 "tests/groundtools/test_mavsdk_geofence_example.py::")


def takes_turns(nodeid: str) -> bool:
    return nodeid.startswith(ONE_AT_A_TIME)


def pytest_addoption(parser: pytest.Parser) -> None:
    group = parser.getgroup("ivfm scheduling")
    group.addoption("--longest-first", action="store_true",
                    help="with -n: send the longest tests first (tests/process_durations.json)")
    group.addoption("--record-durations", action="store_true",
                    help="write each test's measured duration into the durations file")
    group.addoption("--durations-file", type=Path, default=DURATIONS_FILE,
                    help="the expected durations, seconds by test id (default: %(default)s)")


def expected_durations(path: Path = DURATIONS_FILE) -> dict[str, float]:
    return json.loads(path.read_text()) if path.exists() else {}


def longest_first(nodeids: list[str], durations: dict[str, float]) -> list[int]:
    """Indices of ``nodeids``, longest expected first; ties keep collection order."""
    return sorted(range(len(nodeids)), key=lambda i: -durations.get(nodeids[i], UNKNOWN_S))


def _scheduler_class():
    from xdist.scheduler import WorkStealingScheduling

    class LongestFirstScheduling(WorkStealingScheduling):
        """Work stealing's bookkeeping, with its own hand-out: the pending tests sorted
        longest first, and each worker topped up one test at a time, round robin, so the
        longest flights start together on different workers. Nothing is ever stolen."""

        def __init__(self, config: pytest.Config, log=None) -> None:
            super().__init__(config, log)
            self._sorted = False

        def check_schedule(self) -> None:
            if self.collection is None:
                return
            if not self._sorted:  # once, when the collection is in
                durations = expected_durations(self.config.getoption("durations_file"))
                self.pending[:] = [self.pending[i] for i in longest_first(
                    [self.collection[j] for j in self.pending], durations)]
                self._sorted = True
            up = [node for node in self.node2pending if not node.shutting_down]
            while self.pending:
                short = [n for n in up if len(self.node2pending[n]) < QUEUED_PER_WORKER]
                sent = False
                for node in short:
                    at = self._next_sendable()
                    if at is not None:
                        self.pending.insert(0, self.pending.pop(at))
                        self._send_tests(node, 1)
                        sent = True
                if not sent:
                    return  # workers full, or what is left waits for its turn
            for node in up:
                if len(self.node2pending[node]) < QUEUED_PER_WORKER:
                    node.shutdown()  # nothing left to send: run the last test now

        def _next_sendable(self) -> int | None:
            """Where in ``pending`` the longest test that may go now is: not one that
            takes turns while another of them is queued or running."""
            busy = any(takes_turns(self.collection[i])
                       for queued in self.node2pending.values() for i in queued)
            for at, i in enumerate(self.pending):
                if not (busy and takes_turns(self.collection[i])):
                    return at
            return None

    return LongestFirstScheduling


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_make_scheduler(config: pytest.Config, log):
    if not config.getoption("longest_first"):
        return None
    return _scheduler_class()(config, log)


class DurationRecorder:
    """On the controller (or a run without workers): each test's phases summed."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.measured_s: dict[str, float] = defaultdict(float)

    def pytest_runtest_logreport(self, report: pytest.TestReport) -> None:
        self.measured_s[report.nodeid] += report.duration

    def pytest_sessionfinish(self) -> None:
        durations = expected_durations(self.path)
        durations.update({k: round(v, 1) for k, v in self.measured_s.items()})
        self.path.write_text(json.dumps(dict(sorted(durations.items())), indent=0) + "\n")


def pytest_configure(config: pytest.Config) -> None:
    worker = hasattr(config, "workerinput")
    if config.getoption("record_durations") and not worker:
        config.pluginmanager.register(DurationRecorder(config.getoption("durations_file")),
                                      "ivfm-duration-recorder")
