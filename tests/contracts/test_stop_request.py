"""The stop request a signal handler may set (the logger once deadlocked on Ctrl-C)."""

from __future__ import annotations

import faulthandler
import os
import signal
import threading
import time

from contracts.stop_request import StopRequest


def test_wait_times_out_unasked_and_returns_at_once_when_asked():
    stop = StopRequest()
    t0 = time.monotonic()
    assert stop.wait(0.05) is False
    assert 0.05 <= time.monotonic() - t0 < 1.0
    stop.set()
    assert stop.is_set() and stop.wait(10.0) is True and stop.wait() is True


def test_set_from_another_thread_ends_an_unbounded_wait():
    stop = StopRequest()
    threading.Timer(0.05, stop.set).start()
    assert stop.wait(timeout_s=None) is True


def test_signals_sent_while_the_main_thread_waits_end_the_wait():
    """Signals land at random points of a busy wait loop, hundreds of times. With a
    threading.Event in its place (handler ``event.set``, loop ``event.wait(0)``) this
    deadlocks within the first hundred signals: the handler waits for the lock the
    interrupted ``wait`` holds. The watchdog turns such a hang into a failure."""
    previous = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    faulthandler.dump_traceback_later(60.0, exit=True)
    try:
        for signum in [signal.SIGINT, signal.SIGTERM] * 200:
            stop = StopRequest()
            stop.on_signals()
            threading.Timer(0.001, os.kill, (os.getpid(), signum)).start()
            assert stop.wait(timeout_s=5.0, poll_s=0.0) is True
    finally:
        faulthandler.cancel_dump_traceback_later()
        for signum, handler in previous.items():
            signal.signal(signum, handler)
