"""Work a module's tests share, done once per test run even when pytest-xdist sends them
to different workers: a module-scoped fixture runs once in every worker that gets one of
its tests, and the x500 rehearsal (35 s of CPU) ran twice in CI for its two tests.

The first worker to ask does the work in a folder of the run's own temporary root (the
one every worker of this run shares: pytest-xdist's documented pattern), under a file
lock, and writes its JSON answer there; the others wait on the lock and read it. Without
xdist the work is simply done."""

from __future__ import annotations

import fcntl
import json
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest


def once(tmp_path_factory: pytest.TempPathFactory, worker_id: str, name: str,
         work: Callable[[Path], Any]) -> tuple[Path, Any]:
    """(folder, answer) of ``work(folder)``, done once in this test run; the answer must
    be JSON."""
    if worker_id == "master":  # no xdist: this process is the run
        folder = tmp_path_factory.mktemp(name)
        return folder, work(folder)
    shared = tmp_path_factory.getbasetemp().parent  # this run's root, every worker's
    folder, answer_file = shared / name, shared / f"{name}.json"
    with open(shared / f"{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if answer_file.exists():
            return folder, json.loads(answer_file.read_text())
        folder.mkdir()
        answer = work(folder)
        answer_file.write_text(json.dumps(answer))
        return folder, answer
