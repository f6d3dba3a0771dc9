"""A stop asked of a process's loop, from another thread or from a signal handler.

Not a ``threading.Event``: a signal handler runs in the main thread between two bytecodes,
possibly while that thread is inside ``Event.wait`` holding the event's own lock, and
``Event.set`` in the handler then waits for that lock forever. The logger did exactly that
on Ctrl-C (one stop in about 40 under load), and was killed with its file unfinished. A
plain attribute takes no lock, so setting it is safe anywhere.
"""

from __future__ import annotations

import signal
import time


class StopRequest:
    """Set once, from anywhere; the loop polls it or sleeps on it in short steps."""

    def __init__(self) -> None:
        self._asked = False

    def set(self, *_signal_args: object) -> None:
        """Ask the loop to stop (also a signal handler: ``signal.signal(SIGINT, r.set)``)."""
        self._asked = True

    def is_set(self) -> bool:
        return self._asked

    def wait(self, timeout_s: float | None = None, poll_s: float = 0.005) -> bool:
        """Until asked, or ``timeout_s`` (None: no limit); whether it was asked."""
        deadline = None if timeout_s is None else time.monotonic() + timeout_s
        while not self._asked:
            if deadline is None:
                time.sleep(poll_s)
                continue
            left_s = deadline - time.monotonic()
            if left_s <= 0:
                break
            time.sleep(min(poll_s, left_s))
        return self._asked

    def on_signals(self, *signums: int) -> None:
        """Be set by these signals (SIGINT and SIGTERM by default); main thread only."""
        for signum in signums or (signal.SIGINT, signal.SIGTERM):
            signal.signal(signum, self.set)
