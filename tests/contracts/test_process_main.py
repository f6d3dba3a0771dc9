"""The vehicle processes' entry shell (contracts/process_main.py): ending with the command
that started them itself."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from contracts.process_main import END_WITH_ENV, end_with_command

ROOT = Path(__file__).parents[2]


@pytest.mark.parametrize("value", ["", "x", "-3", "0", "1.5", "٣"])
def test_a_bad_command_pid_is_said_and_ignored(monkeypatch, capsys, value):
    monkeypatch.setenv(END_WITH_ENV, value)
    signalled = []  # a regression signals this test process: recorded, not sent
    monkeypatch.setattr("contracts.process_main.os.kill", lambda *a: signalled.append(a))
    end_with_command()
    assert not signalled
    said = capsys.readouterr().err
    assert ("not a process id: ignored" in said) == (value != "")


@pytest.mark.process
def test_a_process_whose_command_has_already_gone_stops_at_once():
    """Its parent is not the command it names (the command ended before it started): it
    stops on SIGTERM, as it would have when the command ended. Named by its parent, it
    goes on."""
    code = "from contracts.process_main import end_with_command; end_with_command(); " \
           "print('still here')"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          cwd=ROOT, env={"PATH": "/usr/bin:/bin", END_WITH_ENV: "99999999"})
    assert done.returncode == -signal.SIGTERM
    assert "still here" not in done.stdout
    fine = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          cwd=ROOT, env={"PATH": "/usr/bin:/bin", END_WITH_ENV: str(os.getpid())})
    assert fine.stdout.strip() == "still here"
