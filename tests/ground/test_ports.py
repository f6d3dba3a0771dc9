"""Ports for a run's children (ground/run/children.py ``free_port``): claimed below the
kernel's ephemeral range so that runs and tests starting together are never handed the
same one (bind(0) hands a probed port out again as soon as the probe closes)."""

from __future__ import annotations

import os
import socket
import time
from pathlib import Path

import pytest

from ground.run import children
from ground.run.children import PORT_LEASE_S, PORTS_FOLDER, free_port


@pytest.fixture
def claims(tmp_path, monkeypatch) -> Path:
    """The claims of this test alone (the machine's other runs keep theirs)."""
    monkeypatch.setattr(children.tempfile, "gettempdir", lambda: str(tmp_path))
    return tmp_path / PORTS_FOLDER


def _ephemeral_low() -> int:
    return int(Path("/proc/sys/net/ipv4/ip_local_port_range").read_text().split()[0])


def test_ports_are_claimed_below_the_ephemeral_range_and_never_handed_out_twice(claims):
    ports = [free_port(kind) for kind in (socket.SOCK_STREAM, socket.SOCK_DGRAM) * 150]
    assert len(set(ports)) == len(ports)
    low = _ephemeral_low()
    assert all(low - children.PORT_SPAN <= p < low for p in ports)
    # Each one claimed (and any in use on the machine meanwhile claimed and passed over).
    assert set(ports) <= {int(f.name) for f in claims.iterdir()}
    assert claims.stat().st_mode & 0o1777 == 0o1777  # any user's runs claim there too


def test_pickers_at_the_same_time_get_other_ports(claims):
    """Pickers at once (two runs of ``ivfm check -j 2``; here threads, which meet at the
    same claim files as processes do): no port in common."""
    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(4) as pool:
        picked = list(pool.map(lambda _: [free_port() for _ in range(100)], range(4)))
    ports = [p for ours in picked for p in ours]
    assert len(set(ports)) == 400


def test_a_standing_claim_or_a_port_in_use_is_skipped_and_a_claim_run_out_retaken(
        claims, monkeypatch):
    monkeypatch.setattr(children, "PORT_SPAN", 3)
    low = _ephemeral_low()
    first, second, third = low - 3, low - 2, low - 1
    claims.mkdir()
    (claims / str(first)).touch()  # claimed by another run just now
    stale = claims / str(second)
    stale.touch()
    old = time.time() - PORT_LEASE_S - 1.0
    os.utime(stale, (old, old))  # claimed long ago: run out
    with socket.socket() as taken:  # in use by someone who never claimed it
        try:
            taken.bind(("127.0.0.1", third))
        except OSError:
            pytest.skip(f"port {third} is in use on this machine")
        assert free_port() == second
        assert stale.stat().st_mtime > old  # claimed anew
        with pytest.raises(OSError, match="no free port"):
            free_port()
