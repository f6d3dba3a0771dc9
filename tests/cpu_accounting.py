"""Where the process tier's CPU goes: each test's wall time and the CPU of the test
process and of the processes it started and waited for (getrusage: the simulator, the
autopilot, the logger, ``ivfm`` commands, MAVProxy; MAVSDK runs inside the test
process). A pytest plugin, loaded only when asked:

    IVFM_CPU_REPORT=cpu.jsonl python -m pytest -m process -n 4 -p tests.cpu_accounting

appends one JSON line per test (``test``, ``wall_s``, ``self_cpu_s``,
``children_cpu_s``) to the file; each xdist worker accounts for its own tests. A child
still running when its test ends is counted by the test that waits for it; a process
forked by a process loader of the test process (tests/harness.py) is counted when the
loader says it ended (ground/run/loader.py ``FORKED_CPU_S``), and the loader's own
loading when the loader ends. The tier is bound by CPU on 2 CPUs: docs/developing.md
says what it showed.
"""

from __future__ import annotations

import json
import os
import resource
import time

import pytest

ENV = "IVFM_CPU_REPORT"


def _cpu_s() -> tuple[float, float]:
    from ground.run.loader import FORKED_CPU_S

    own = resource.getrusage(resource.RUSAGE_SELF)
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime, children.ru_utime + children.ru_stime + FORKED_CPU_S[0]


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item: pytest.Item, nextitem: pytest.Item | None):
    out = os.environ.get(ENV)
    if not out:
        yield
        return
    own, children = _cpu_s()
    started = time.monotonic()
    yield
    own_after, children_after = _cpu_s()
    with open(out, "a") as f:
        f.write(json.dumps({"test": item.nodeid, "wall_s": round(time.monotonic() - started, 3),
                            "self_cpu_s": round(own_after - own, 3),
                            "children_cpu_s": round(children_after - children, 3)}) + "\n")
