"""The inbox between Zenoh's threads and the logger's (or live view's) loop: its bounds, and
the memory of a backlog given back once drained (ground/telemetry/inbox.py)."""

from __future__ import annotations

import sys
import threading

import pytest

from ground.telemetry.inbox import RELEASE_AFTER_BYTES, Inbox, release_free_memory


def test_an_inbox_refuses_past_its_entries_or_its_bytes_and_takes_again_once_drained():
    inbox = Inbox(max_entries=3, max_bytes=100, release=lambda: None)
    assert inbox.put(("a", 1), 40) and inbox.put(("b", 2), 40)
    assert not inbox.put(("c", 3), 21)  # 101 bytes waiting: over
    assert inbox.put(("c", 3), 20)  # 100: at the bound
    assert (len(inbox), inbox.waiting_bytes) == (3, 100)
    assert not inbox.put(("d", 4), 0)  # 3 entries: full
    written: list[tuple[str, int]] = []
    assert inbox.drain(lambda *entry: written.append(entry)) == 3
    assert written == [("a", 1), ("b", 2), ("c", 3)]  # oldest first, as put
    assert (len(inbox), inbox.waiting_bytes) == (0, 0)
    assert inbox.put(("d", 4), 100)


def test_only_a_drain_of_a_backlog_gives_memory_back():
    released = []
    inbox = Inbox(1000, 10**9, release_after_bytes=1000, release=lambda: released.append(1))
    for _ in range(9):
        inbox.put((b"",), 111)  # 999 bytes: a drain of less than the threshold
    inbox.drain(lambda _payload: None)
    assert released == [] and inbox.releases == 0
    for _ in range(10):
        inbox.put((b"",), 100)  # 1000
    inbox.drain(lambda _payload: None)
    assert released == [1] and inbox.releases == 1
    inbox.drain(lambda _payload: None)  # nothing waiting: nothing to give back
    assert released == [1]


def _rss_mib() -> float:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    raise RuntimeError("no VmRSS")


@pytest.mark.skipif(not sys.platform.startswith("linux") or not release_free_memory(),
                    reason="glibc's malloc_trim (Linux)")
def test_the_memory_a_backlog_held_is_back_after_the_drain():
    """64 MiB of records put by another thread (Zenoh's, whose malloc arena holds them),
    drained by this one: without the release, glibc kept all of it (RSS stayed at the
    peak, measured); with it, RSS is back to within a few MiB of before."""
    inbox = Inbox(1_000_000, 10**9)
    record_bytes = 10_000  # a batch of 20 ms of one vehicle's records at 250 Hz
    records = 64 * 2**20 // record_bytes

    def receive() -> None:
        for i in range(records):
            payload = bytes([i % 251]) * record_bytes  # allocated here, as to_bytes() is
            inbox.put((payload,), len(payload))

    release_free_memory()
    before_mib = _rss_mib()
    thread = threading.Thread(target=receive)
    thread.start()
    thread.join()
    peak_mib = _rss_mib()
    assert inbox.drain(lambda _payload: None) == records
    after_mib = _rss_mib()
    assert inbox.releases == 1 and records * record_bytes >= RELEASE_AFTER_BYTES
    assert peak_mib - before_mib > 56.0  # the backlog was resident
    assert after_mib - before_mib < 6.0, (before_mib, peak_mib, after_mib)
