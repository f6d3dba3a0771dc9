"""The process tier's scheduler (tests/scheduling.py): longest tests first, one per worker."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

import pytest

from tests.scheduling import UNKNOWN_S, longest_first


def test_longest_first_orders_by_expected_duration_and_keeps_ties_in_collection_order():
    ids = ["a", "b", "c", "d"]
    durations = {"a": 1.0, "b": 30.0, "d": 30.0}  # c is unknown: UNKNOWN_S
    assert UNKNOWN_S < 30.0
    assert longest_first(ids, durations) == [1, 3, 2, 0]


@pytest.mark.process
def test_each_worker_starts_on_one_of_the_longest_and_the_run_records_durations(
        pytester, monkeypatch):
    """Six tests collected shortest first; two workers. Stock xdist hands each a
    contiguous slice, so a worker would start on t1 (the shortest). Longest first, the
    workers start on t6 and t5."""
    monkeypatch.setenv("PYTHONPATH", str(Path(__file__).resolve().parents[1]))  # tests.*
    expected = {f"test_scheduled.py::test_t{k}": 100.0 + k for k in range(1, 7)}
    durations = pytester.path / "durations.json"
    durations.write_text(json.dumps(expected))
    pytester.makepyfile(test_scheduled="\n".join([
        "import os, time",
        "def _note(name):",
        "    with open('starts.txt', 'a') as f:",
        "        f.write(os.environ['PYTEST_XDIST_WORKER'] + ' ' + name + '\\n')",
        "    time.sleep(0.1)",
        *(f"def test_t{k}():\n    _note('t{k}')" for k in range(1, 7))]))
    result = pytester.runpytest_subprocess(
        "-p", "tests.scheduling", "-n", "2", "--longest-first", "--record-durations",
        f"--durations-file={durations}")
    result.assert_outcomes(passed=6)
    first_by_worker: dict[str, str] = {}
    for line in (pytester.path / "starts.txt").read_text().splitlines():
        worker, name = line.split()
        first_by_worker.setdefault(worker, name)
    assert sorted(first_by_worker.values()) == ["t5", "t6"]
    recorded = json.loads(durations.read_text())
    assert set(recorded) == set(expected)
    assert all(0.1 <= seconds < 100.0 for seconds in recorded.values()), recorded  # measured


@pytest.mark.process
def test_tests_that_take_turns_never_run_together(pytester, monkeypatch):
    """Two tests of a file in ONE_AT_A_TIME, the two longest, and four others; two
    workers. Longest first alone would start the two together (one waiting on the
    other's lock in a real run); here the second waits its turn (the hand-out itself:
    the next test)."""
    monkeypatch.setenv("PYTHONPATH", str(Path(__file__).resolve().parents[1]))
    note = "\n".join([
        "import os, time",
        "def _note(name, seconds):",
        "    start = time.monotonic()",
        "    time.sleep(seconds)",
        "    with open(os.path.join(os.environ['NOTES'], 'runs.txt'), 'a') as f:",
        "        f.write(f'{name} {start} {time.monotonic()}\\n')"])
    turns = pytester.mkdir("tests").joinpath("groundtools")
    turns.mkdir()
    (turns / "test_mavsdk_examples.py").write_text(note + "\n" + "\n".join(
        f"def test_g{k}():\n    _note('g{k}', 0.6)" for k in (1, 2)) + "\n")
    pytester.makepyfile(test_other=note + "\n" + "\n".join(
        f"def test_o{k}():\n    _note('o{k}', 0.2)" for k in range(1, 5)) + "\n")
    durations = pytester.path / "durations.json"
    durations.write_text(json.dumps({
        "tests/groundtools/test_mavsdk_examples.py::test_g1": 20.0,
        "tests/groundtools/test_mavsdk_examples.py::test_g2": 19.0}))
    monkeypatch.setenv("NOTES", str(pytester.path))
    result = pytester.runpytest_subprocess(
        "-p", "tests.scheduling", "-n", "2", "--longest-first",
        f"--durations-file={durations}")
    result.assert_outcomes(passed=6)
    runs = {name: (float(start), float(end)) for name, start, end in (
        line.split() for line in (pytester.path / "runs.txt").read_text().splitlines())}
    (g1_start, g1_end), (g2_start, g2_end) = runs["g1"], runs["g2"]
    assert g2_start >= g1_end or g1_start >= g2_end, runs


class _Worker:
    """What the scheduler asks of an xdist worker: take tests, shut down."""

    def __init__(self, name: str) -> None:
        self.gateway = SimpleNamespace(id=name)
        self.shutting_down, self.sent = False, []

    def send_runtest_some(self, indices: list[int]) -> None:
        self.sent += indices

    def shutdown(self) -> None:
        self.shutting_down = True


def test_a_test_that_takes_turns_waits_while_the_next_longest_ones_go_out(tmp_path):
    """The hand-out itself, on the scheduler with two stand-in workers: g1 and g2 (one
    file of ONE_AT_A_TIME) are the longest; g2 goes out only once g1 is done, the others
    in the meantime, longest first; the workers are shut down when nothing is left."""
    from tests.scheduling import _scheduler_class

    turns = "tests/groundtools/test_mavsdk_examples.py::"
    collection = ["test_o.py::o1", "test_o.py::o2", "test_o.py::o3", f"{turns}g1",
                  f"{turns}g2"]
    durations = tmp_path / "durations.json"
    durations.write_text(json.dumps({f"{turns}g1": 30.0, f"{turns}g2": 20.0,
                                     "test_o.py::o3": 10.0}))
    options = {"tx": ["2*popen"], "durations_file": durations}
    config = SimpleNamespace(getvalue=options.get, getoption=options.get)  # xdist reads these
    scheduler = _scheduler_class()(config)
    a, b = _Worker("a"), _Worker("b")
    for worker in (a, b):
        scheduler.add_node(worker)
        scheduler.add_node_collection(worker, collection)
    scheduler.schedule()
    names = {i: name.split("::")[1] for i, name in enumerate(collection)}
    assert [names[i] for i in a.sent] == ["g1", "o1"]  # o1 and o2 tie at 8 s: in order
    assert [names[i] for i in b.sent] == ["o3", "o2"]
    scheduler.mark_test_complete(b, b.sent[0])  # o3 done: g1 still runs, nothing may go
    assert len(b.sent) == 2 and not b.shutting_down
    scheduler.mark_test_complete(a, a.sent[0])  # g1 done: g2's turn
    assert [names[i] for i in a.sent + b.sent].count("g2") == 1
    for worker in (a, b):
        for index in list(scheduler.node2pending[worker]):
            scheduler.mark_test_complete(worker, index)
    assert a.shutting_down and b.shutting_down and scheduler.tests_finished
