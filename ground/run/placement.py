"""Where lockstep runs fly on this machine: the CPU a run's two loops share
(``HandoverCpus``), and a batch's places to fly (``FlightSlots``: ``ivfm check``), so
that runs in flight together keep off each other's loops (docs/mavlink.md, "The lockstep
cycle through the processes"; docs/checks.md)."""

from __future__ import annotations

import contextlib
import fcntl
import os
import tempfile
import threading
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

from contracts.realtime import pin_to_cpus


class HandoverCpus:
    """The CPU each lockstep run's two loops share, over every run on this machine in
    flight (``ivfm check -j N``, a campaign's workers, several ``ivfm run``): a run takes
    a CPU by locking its file in ``lock_dir`` (the last CPU first: CPU 0 serves most
    interrupts), and none when every CPU is taken (it runs unplaced, as before) or the
    machine has one CPU. A lock goes with its process, however that ends.

    While it holds CPUs, this process (the command: its waits, its Zenoh session) keeps
    its own threads off them, through ``keep_off`` (CPUs it may use), and goes back to
    the CPUs it had once it holds none: its wake-ups on a hand-over CPU preempted the
    loops there (docs/mavlink.md, "The lockstep cycle through the processes")."""

    def __init__(self, lock_dir: Path | None = None,
                 keep_off: Callable[[frozenset[int]], object] | None = None) -> None:
        self.lock_dir = Path(lock_dir or tempfile.gettempdir())
        self._held: dict[int, int] = {}  # cpu -> the locked file's descriptor
        self._lock = threading.Lock()
        self._place = keep_off or pin_to_cpus
        self._own: frozenset[int] = frozenset()  # this process's CPUs before it held any

    def take(self) -> int | None:
        with self._lock:
            if not self._held:
                self._own = frozenset(os.sched_getaffinity(0))
            cpus = sorted(self._own, reverse=True)
            if len(cpus) < 2:
                return None
            for cpu in cpus:
                if cpu in self._held:
                    continue
                fd = os.open(self.lock_dir / f"ivfm-handover-cpu{cpu}.lock",
                             os.O_CREAT | os.O_RDWR, 0o666)
                try:
                    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                except OSError:  # another run's
                    os.close(fd)
                    continue
                self._held[cpu] = fd
                self._keep_off_held()
                return cpu
        return None

    def give(self, cpu: int | None) -> None:
        with self._lock:
            fd = self._held.pop(cpu, None) if cpu is not None else None
            if fd is not None:
                os.close(fd)  # and its lock
                self._keep_off_held()

    def _keep_off_held(self) -> None:
        """This process on its own CPUs but those it holds (all of them when it holds
        every one: the command then waits beside its runs, as before)."""
        with contextlib.suppress(OSError):
            self._place(self._own - set(self._held) or self._own)


HANDOVER_CPUS = HandoverCpus()


class FlightSlots:
    """Where the runs of one batch (``ivfm check``) fly: ``count`` places, each a hand-over
    CPU taken for the whole batch (None when none is free) and a lock that one run holds
    from its processes being ready until they exit. The other runs meanwhile start their
    processes (placed for their place's CPU, so they are ready to fly the moment it is
    free) or write their reports. ``close`` gives the CPUs back."""

    def __init__(self, count: int, cpus: HandoverCpus = HANDOVER_CPUS) -> None:
        self._cpus = cpus
        self.cpus = [cpus.take() for _ in range(max(1, count))]
        self._locks = [threading.Lock() for _ in self.cpus]
        self._assigned = [0] * len(self.cpus)  # runs assigned to each and not done
        self._lock = threading.Lock()

    @contextlib.contextmanager
    def assign(self) -> Iterator[FlightSlot]:
        """A run's slot (the one with the fewest runs on it), for the run's length."""
        with self._lock:
            i = self._assigned.index(min(self._assigned))
            self._assigned[i] += 1
        try:
            yield FlightSlot(self.cpus[i], self._locks[i])
        finally:
            with self._lock:
                self._assigned[i] -= 1

    def close(self) -> None:
        for cpu in self.cpus:
            self._cpus.give(cpu)
        self.cpus = []


@dataclass(frozen=True)
class FlightSlot:
    """One run's place in ``FlightSlots``: its loops' CPU, and the lock held to fly."""

    cpu: int | None
    lock: threading.Lock
