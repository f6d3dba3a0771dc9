"""What Foxglove draws of each record the logger writes (``foxglove_view``): written into
the same file beside the records (unless only the live view wants it) and handed to a
live view; a record it cannot draw is said (once per key per 5 s) and skipped, its own
record logged as it came."""

from __future__ import annotations

import time
from collections.abc import Callable

from ground.telemetry.foxglove_scene import encode
from ground.telemetry.foxglove_view import FoxgloveView, Output
from ground.telemetry.log_files import Counters, LogFiles


class Drawing:
    """The Foxglove view of one logger, fed record by record as they are written."""

    def __init__(self, rate_hz: float, write: bool, live: Callable[[Output], None] | None,
                 files: LogFiles, counters: Counters, log: Callable[[str], None]) -> None:
        self.view = FoxgloveView(rate_hz)
        self.write = write  # into the file beside the records
        self.live = live  # a live view's publish (ground/telemetry/live_view.py), or None
        self.files = files
        self.counters = counters
        self.log = log
        self._warned: dict[str, float] = {}

    def draws(self, key: str) -> bool:
        return self.view.draws(key)

    def draw(self, key: str, payload: bytes, attachment: bytes | None,
             log_time_ns: int) -> None:
        """What Foxglove draws of this record, into the file and to the live view."""
        c = self.counters
        try:
            outputs = self.view.feed(key, payload, attachment)
        except (ValueError, TypeError, KeyError) as exc:
            c.view_refused += 1
            self._refuse(key, str(exc))
            return
        f = self.files.file
        for output in outputs:
            if self.live is not None:
                self.live(output)
            if not self.write:
                continue
            try:
                f.add(f.view_channel(output), log_time_ns, output.sim_time_ns, 0,
                      encode(output.message))
            except OSError as exc:
                self.files.write_failed(exc)
                return
            c.view_messages += 1

    def _refuse(self, key: str, reason: str) -> None:
        now = time.monotonic()
        if now - self._warned.get(key, -10.0) > 5.0:
            self._warned[key] = now
            self.log(f"cannot draw a record on {key}: {reason} (logged as it came; "
                     f"{self.counters.view_refused} so far)")
