"""Records that Zenoh's threads hand to a loop (the logger's, the live view's): bounded in
entries and in bytes, and the memory a backlog held given back to the system once the
loop has caught up (docs/realtime.md, "The logger's memory").

Why the giving back: a record's bytes are allocated by the Zenoh thread that received
it, in that thread's glibc malloc arena, and freed by the loop once written. glibc keeps
what is freed inside the arena for reuse; it returns it to the system only from the top
of a heap, and a few live allocations above stop even that. So a backlog (the loop
starved of CPU for seconds while records kept coming) left the process's resident memory
at its peak for good: each higher backlog raised it again, which is how a soak's logger
grew for as long as its CPU was contended and then stayed flat. ``malloc_trim`` hands the
free pages of every arena back; it is called once a drain has taken at least
``release_after_bytes``. After backlogs of 29-80 MiB the resident memory came back to
4-14 MiB above where it was (measured; what glibc still keeps is in the docs), and
further backlogs did not add to it.
"""

from __future__ import annotations

import collections
import ctypes
import threading
from collections.abc import Callable
from typing import Any

RELEASE_AFTER_BYTES = 2 * 1024 * 1024  # a drain of this much (~3.5 s of one vehicle's
# records at 250 Hz) leaves its memory to be given back; the loop's usual drain, a few
# milliseconds of records, never does


def _malloc_trim() -> Callable[[], Any] | None:
    """glibc's malloc_trim, from the symbols already loaded into this process (not
    ``ctypes.util.find_library``, which runs ldconfig at import)."""
    try:
        trim = ctypes.CDLL(None).malloc_trim
    except (OSError, AttributeError):  # not glibc (musl, macOS): nothing to call
        return None
    trim.argtypes, trim.restype = [ctypes.c_size_t], ctypes.c_int
    return trim


_TRIM = _malloc_trim()


def release_free_memory() -> bool:
    """Give the free pages of every malloc arena back to the system (glibc
    ``malloc_trim(0)``: ~15 ms for 100 MiB, ~40 us with nothing to give). False where
    there is no such call."""
    if _TRIM is None:
        return False
    _TRIM(0)
    return True


class Inbox:
    """Entries put by Zenoh's callback threads, drained by one loop thread.

    ``put`` refuses an entry (False; the caller counts it) with ``max_entries`` waiting or
    when its ``size_bytes`` would take the bytes waiting past ``max_bytes``. ``drain``
    hands every entry to ``write`` until none is left and, when it took at least
    ``release_after_bytes``, calls ``release`` (the memory the backlog held)."""

    def __init__(self, max_entries: int, max_bytes: int,
                 release_after_bytes: int = RELEASE_AFTER_BYTES,
                 release: Callable[[], Any] = release_free_memory) -> None:
        self.max_entries, self.max_bytes = max_entries, max_bytes
        self.release_after_bytes = release_after_bytes
        self.release = release
        self._entries: collections.deque[tuple[tuple, int]] = collections.deque()
        self._lock = threading.Lock()  # callbacks may come from several Zenoh threads
        self._bytes_in = 0  # put so far (callback threads, under the lock)
        self._bytes_out = 0  # drained so far (the loop thread only)
        self.releases = 0  # times a drained backlog's memory was given back

    def __len__(self) -> int:
        return len(self._entries)

    @property
    def waiting_bytes(self) -> int:
        return self._bytes_in - self._bytes_out

    def put(self, entry: tuple, size_bytes: int) -> bool:
        with self._lock:
            if (len(self._entries) >= self.max_entries
                    or self._bytes_in - self._bytes_out + size_bytes > self.max_bytes):
                return False
            self._bytes_in += size_bytes
            self._entries.append((entry, size_bytes))
        return True

    def drain(self, write: Callable[..., Any]) -> int:
        """``write(*entry)`` for every entry, oldest first, until none is left; the count."""
        n = taken = 0
        entries = self._entries
        while entries:
            entry, size_bytes = entries.popleft()
            self._bytes_out += size_bytes
            taken += size_bytes
            write(*entry)
            n += 1
        if taken >= self.release_after_bytes:
            self.release()
            self.releases += 1
        return n
