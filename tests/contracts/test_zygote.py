"""The process loader (contracts/zygote.py, ground/run/loader.py): its requests checked,
and the processes it forks behaving as fresh ones."""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path

import pytest

from ground.run.loader import FORKED_CPU_S, ProcessLoader, ProcessRunError


@pytest.mark.process
def test_the_process_loader_refuses_bad_requests_and_keeps_serving(tmp_path):
    """A bad request is answered and changes nothing; a run whose arguments are refused,
    or that asks for help, ends as a fresh process would, its words in its log; signals
    reach the forked process; end of input ends the loader."""
    loader = ProcessLoader(("sitl",))
    try:
        with pytest.raises(ProcessRunError, match="module must be one of sitl"):
            loader.start("autopilot", [], tmp_path / "x.log")
        with pytest.raises(ProcessRunError, match="Is a directory"):
            loader.start("sitl", [], tmp_path)
        with pytest.raises(ProcessRunError, match="No such file or directory"):
            loader.start("sitl", [], tmp_path / "no" / "such" / "folder.log")
        bad = loader.start("sitl", ["--rate-hz", "banana"], tmp_path / "bad.log")
        assert bad.wait(timeout=30) == 2
        assert "argument --rate-hz: must be a number in [1, 2000] Hz, got 'banana'" in \
            (tmp_path / "bad.log").read_text()
        used_before = FORKED_CPU_S[0]
        helped = loader.start("sitl", ["--help"], tmp_path / "help.log")
        assert helped.wait(timeout=30) == 0
        assert FORKED_CPU_S[0] > used_before  # its CPU time, said with its end
        assert "--lockstep" in (tmp_path / "help.log").read_text()
        held = loader.start("sitl", ["--hold", "--port", "0", "--zenoh-listen",
                                     "tcp/127.0.0.1:0"], tmp_path / "held.log",
                            env={"IVFM_PROBE": "1"})
        assert held.poll(timeout_s=0.5) is None  # waits to be released
        held.send_signal(signal.SIGKILL)
        assert held.wait(timeout=30) == -signal.SIGKILL
        assert loader.alive
    finally:
        loader.close()
    assert loader.alive is False  # end of input ended it


@pytest.mark.parametrize(("line", "message"), [
    ("{", "one JSON object per line"),
    ("[]", "the fields id, module, argv and log"),
    ('{"id": 1, "module": "sitl", "argv": [], "log": "x", "more": 1}', "the fields"),
    ('{"id": true, "module": "sitl", "argv": [], "log": "x"}', "id must be an integer"),
    ('{"id": 1, "module": "os", "argv": [], "log": "x"}', "module must be one of sitl"),
    ('{"id": 1, "module": "sitl", "argv": [1], "log": "x"}', "argv must be a list of strings"),
    ('{"id": 1, "module": "sitl", "argv": [], "log": ""}', "log must be a file path"),
    ('{"id": 1, "module": "sitl", "argv": [], "log": "x", "env": {"A=B": "1"}}',
     "env must map variable names"),
    ('{"id": 1, "module": "sitl", "argv": [], "log": "x", "env": {"A": 1}}',
     "env must map variable names"),
    ('{"id": 1, "module": "sitl", "argv": [], "log": "x", "cwd": ""}', "cwd must be a folder"),
])
def test_process_loader_requests_are_checked(line, message):
    from contracts.zygote import parse_request

    with pytest.raises(ValueError) as err:
        parse_request(line, frozenset({"sitl"}))
    assert message in str(err.value)
    assert parse_request('{"id": 3, "module": "sitl", "argv": ["--port", "1"], "log": "/l"}',
                         frozenset({"sitl"}))["argv"] == ["--port", "1"]


@pytest.mark.process
def test_a_forked_process_has_its_environment_and_the_terminals_ctrl_c(tmp_path):
    """The variables a start names reach the process (its timeline marks go where
    IVFM_TIMELINE says); SIGINT, as a Ctrl-C in the terminal sends it to every process of
    the command, ends a held simulator and leaves the loader serving."""
    import json

    loader = ProcessLoader(("sitl",))
    try:
        marks = tmp_path / "timeline.raw"
        helped = loader.start("sitl", ["--help"], tmp_path / "help.log",
                              env={"IVFM_TIMELINE": str(marks)})
        assert helped.wait(timeout=30) == 0
        events = [json.loads(line)["event"] for line in marks.read_text().splitlines()]
        assert events == ["main"]  # --help exits in argparse, before the exit mark
        held = _held_simulator(loader, tmp_path / "held.log")
        os.kill(loader.pid, signal.SIGINT)
        held.send_signal(signal.SIGINT)
        assert held.wait(timeout=30) in (0, 130)
        assert loader.alive
    finally:
        loader.close()


@pytest.mark.process
def test_a_module_the_loader_cannot_import_runs_fresh_and_fails_in_its_log(tmp_path):
    loader = ProcessLoader(("no_such_module_here",))
    try:
        proc = loader.start("no_such_module_here", ["--x"], tmp_path / "log")
        assert proc.wait(timeout=30) == 1
        assert "No module named no_such_module_here" in (tmp_path / "log").read_text()
    finally:
        loader.close()


@pytest.mark.process
def test_a_variable_set_after_the_loader_started_reaches_the_process(tmp_path, monkeypatch):
    """A start sends what differs from the environment the loader started with: a
    variable the command set since (in its own environment, then passed whole) counts."""
    import json

    loader = ProcessLoader(("sitl",))
    try:
        marks = tmp_path / "timeline.raw"
        monkeypatch.setenv("IVFM_TIMELINE", str(marks))
        helped = loader.start("sitl", ["--help"], tmp_path / "help.log", env=dict(os.environ))
        assert helped.wait(timeout=30) == 0
        assert [json.loads(line)["event"] for line in marks.read_text().splitlines()] == \
            ["main"]
    finally:
        loader.close()


@pytest.mark.process
def test_the_end_of_input_ends_what_is_still_running(tmp_path):
    """The command is gone (killed, crashed) while a process of its run still runs: the
    loader stops it (SIGTERM, a clean stop) and exits, instead of leaving it behind."""
    loader = ProcessLoader(("sitl",))
    held = _held_simulator(loader, tmp_path / "held.log")
    start = time.monotonic()
    loader.close()  # the end of its input, as when the command ends
    assert time.monotonic() - start < 5.0  # not the client's 10 s wait and kill
    assert loader.alive is False
    assert not _exists(held.pid)
    assert "stopped at t=" in (tmp_path / "held.log").read_text()  # its own clean stop


def _exists(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    return True


def _held_simulator(loader: ProcessLoader, log: Path):
    """A simulator forked by ``loader`` that waits to be released, once it listens."""
    held = loader.start("sitl", ["--hold", "--port", "0", "--zenoh-listen",
                                 "tcp/127.0.0.1:0"], log)
    deadline = time.monotonic() + 60.0
    while "listening on tcp" not in log.read_text():
        assert held.poll(timeout_s=0.05) is None, log.read_text()
        assert time.monotonic() < deadline, "the held simulator never listened"
    return held


@pytest.mark.process
def test_a_load_freezes_what_it_loaded_and_leaves_the_collector_on(tmp_path):
    """The load runs with the collector off (its collections were a sixth of it); what
    it loaded ends frozen and the collector on again, also when a module fails."""
    import subprocess
    import sys

    probe = ("import gc\nfrom contracts.zygote import load\n"
             "print(load(['sitl', 'no_such_module_here']), gc.isenabled(), "
             "gc.get_freeze_count() > 10_000)")
    done = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                          timeout=120, cwd=Path(__file__).resolve().parents[2])
    assert done.stdout.split() == ["{'sitl':", "True,", "'no_such_module_here':", "False}",
                                   "True", "True"], done.stderr
