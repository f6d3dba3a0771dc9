"""CPUs kept for the real-time processes: ``--rt-cpus`` pins a vehicle process with all
its threads, ``ivfm shield`` moves everything else off those CPUs (docs/realtime.md).
Process tests: they move real processes, and the shield is lifted whatever happens."""

from __future__ import annotations

import os
import subprocess
import sys
import time

import pytest

from contracts.realtime import shield_cpus
from ground.run.children import free_tcp_port

pytestmark = [pytest.mark.process, pytest.mark.alone,  # the shield moves every thread
              pytest.mark.skipif((os.cpu_count() or 1) < 2, reason="needs two CPUs")]
EVERY = set(range(os.cpu_count() or 1))


def _affinity_when(pid: int, wanted: set[int], timeout_s: float = 10.0) -> set[int]:
    deadline = time.monotonic() + timeout_s
    while (got := os.sched_getaffinity(pid)) != wanted and time.monotonic() < deadline:
        time.sleep(0.02)
    return got


def test_the_shield_moves_other_threads_off_and_lifts_again():
    sleeper = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    pinned = subprocess.Popen([sys.executable, "-c", "import os, time; "
                               "os.sched_setaffinity(0, {0}); time.sleep(60)"])
    try:
        assert _affinity_when(pinned.pid, {0}) == {0}
        moved, _refused = shield_cpus(frozenset({0}))
        assert moved >= 1
        assert os.sched_getaffinity(sleeper.pid) == EVERY - {0}
        assert os.sched_getaffinity(pinned.pid) == {0}  # pinned on purpose: left there
        assert os.sched_getaffinity(0) == EVERY - {0}  # this test too
        later = subprocess.run([sys.executable, "-c", "import os; print(sorted("
                                "os.sched_getaffinity(0)))"], capture_output=True, text=True)
        assert later.stdout.strip() == str(sorted(EVERY - {0}))  # what starts now inherits it
    finally:
        shield_cpus(None)
        for proc in (sleeper, pinned):
            proc.kill()
            proc.wait()
    assert os.sched_getaffinity(0) == EVERY


def test_a_pinned_simulator_keeps_every_thread_on_its_cpu(tmp_path):
    log = open(tmp_path / "sitl.txt", "w")  # noqa: SIM115
    sim = subprocess.Popen(
        [sys.executable, "-m", "sitl", "--port", str(free_tcp_port()), "--hold", "--rt-cpus",
         "1", "--zenoh-listen", f"tcp/127.0.0.1:{free_tcp_port()}", "--zenoh-connect", "none"],
        stdout=log, stderr=subprocess.STDOUT)
    try:
        deadline = time.monotonic() + 60.0
        while "listening" not in (tmp_path / "sitl.txt").read_text():
            assert sim.poll() is None and time.monotonic() < deadline
            time.sleep(0.05)
        threads = [int(t) for t in os.listdir(f"/proc/{sim.pid}/task")]
        affinities = {tid: os.sched_getaffinity(tid) for tid in threads}
    finally:
        sim.terminate()
        sim.wait(30)
        log.close()
    assert len(threads) > 1  # Zenoh's threads as well as the loop
    assert set(map(frozenset, affinities.values())) == {frozenset({1})}, affinities
    assert "sitl: pinned to CPU 1" in (tmp_path / "sitl.txt").read_text()


HANDOVER = """
import json, os, threading, time
from contracts.realtime import any_cpu, keep_off_cpu, pin_this_thread
said = [keep_off_cpu(1)]
ready, done = threading.Event(), threading.Event()
other = threading.Thread(target=lambda: (ready.set(), done.wait()))
other.start(); ready.wait()  # started after: inherits the process's placement
said.append(pin_this_thread(1))
placed = {"main": sorted(os.sched_getaffinity(0)),
          "other": sorted(os.sched_getaffinity(other.native_id))}
any_cpu()
placed["after"] = sorted(os.sched_getaffinity(other.native_id))
done.set(); other.join()
print(json.dumps({"said": said, **placed}))
"""


def test_lockstep_loops_take_the_handover_cpu_and_their_other_threads_keep_off_it():
    """--handover-cpu: the process's threads (Zenoh's, started later too) keep off the CPU,
    the loop's thread alone takes it; after the run every thread is back on every CPU
    (a caller that goes on is placed as before)."""
    import json

    out = subprocess.run([sys.executable, "-c", HANDOVER], capture_output=True, text=True,
                         check=True, cwd=os.path.dirname(os.path.dirname(os.path.dirname(
                             os.path.abspath(__file__)))))
    placed = json.loads(out.stdout)
    assert placed["said"] == ["threads kept off CPU 1", "loop on CPU 1"]
    assert placed["main"] == [1]
    assert placed["other"] == sorted(EVERY - {1})
    assert placed["after"] == sorted(EVERY)
