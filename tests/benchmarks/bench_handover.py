"""What one lockstep hand-over costs by transport: two processes pass a sample's bytes
(the simulator's four frames, 300 bytes) and an answer (HIL_ACTUATOR_CONTROLS, 40 bytes)
back and forth, nothing else, as the simulator and the autopilot do each cycle.

    python tests/benchmarks/bench_handover.py                 # both CPUs, then one
    python tests/benchmarks/bench_handover.py --cycles 50000 --rounds 5

Transports: TCP on loopback (PX4's simulator protocol, TCP_NODELAY as both ends set it),
a Unix stream socket, and a pipe pair (the kernel's cheapest byte stream). Each figure
is the round trip (one sample out, one answer back) in microseconds of wall time, the
best round's mean; "one CPU" pins both processes to CPU 0 (the hand-over CPU of
``ivfm check``). Prints figures; asserts nothing.
"""

from __future__ import annotations

import argparse
import os
import socket
import time

SAMPLE = bytes(300)
ANSWER = bytes(40)


def _pair(kind: str) -> tuple[object, object]:
    """(simulator end, autopilot end), each with send(bytes) and recv(n) -> bytes."""
    if kind == "tcp":
        server = socket.socket()
        server.bind(("127.0.0.1", 0))
        server.listen(1)
        client = socket.create_connection(server.getsockname())
        conn, _ = server.accept()
        server.close()
        for s in (client, conn):
            s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        return conn, client
    if kind == "unix":
        return socket.socketpair(socket.AF_UNIX, socket.SOCK_STREAM)
    r1, w1 = os.pipe()
    r2, w2 = os.pipe()
    return _Pipe(r2, w1), _Pipe(r1, w2)


class _Pipe:
    def __init__(self, read_fd: int, write_fd: int) -> None:
        self.read_fd, self.write_fd = read_fd, write_fd

    def sendall(self, data: bytes) -> None:
        os.write(self.write_fd, data)

    def recv(self, n: int) -> bytes:
        return os.read(self.read_fd, n)


def _round_trip_us(kind: str, cycles: int, cpus: set[int] | None) -> float:
    sim, ap = _pair(kind)
    pid = os.fork()
    if pid == 0:  # the autopilot: answer each sample
        if cpus:
            os.sched_setaffinity(0, cpus)
        for _ in range(cycles + 1):
            got = 0
            while got < len(SAMPLE):
                got += len(ap.recv(65536))
            ap.sendall(ANSWER)
        os._exit(0)
    if cpus:
        os.sched_setaffinity(0, cpus)
    sim.sendall(SAMPLE)  # a first cycle, untimed
    sim.recv(65536)
    start = time.perf_counter()
    for _ in range(cycles):
        sim.sendall(SAMPLE)
        got = 0
        while got < len(ANSWER):
            got += len(sim.recv(65536))
    elapsed = time.perf_counter() - start
    os.waitpid(pid, 0)
    return elapsed / cycles * 1e6


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cycles", type=int, default=20_000)
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args()
    everywhere = os.sched_getaffinity(0)
    print(f"round trip per cycle [us], best of {args.rounds} rounds of {args.cycles}")
    for label, cpus in (("both CPUs", None), ("one CPU", {min(everywhere)})):
        for kind in ("tcp", "unix", "pipe"):
            best = min(_round_trip_us(kind, args.cycles, cpus) for _ in range(args.rounds))
            print(f"  {label:<10} {kind:<5} {best:7.1f}")
        os.sched_setaffinity(0, everywhere)


if __name__ == "__main__":
    main()
