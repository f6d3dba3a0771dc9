"""MAVLink 2 signing as the spec asks, in process on real loopback UDP: the signing clock
and each stream's last timestamp kept across a restart, so a signed frame captured
before the restart is refused after it; SETUP_SIGNING taken only over a signed link or
from this machine."""

from __future__ import annotations

import socket

import pytest
from pymavlink.dialects.v20 import common as mavlink

from autopilot.commander.commander import Commander
from autopilot.control.factory import make_controller
from autopilot.mavlink.link import open_link
from autopilot.mavlink.server import MavlinkServer
from autopilot.mavlink.signing import SigningState, is_local, signing_clock_now
from contracts.airframe import PAPER

KEY = bytes(range(32))
M = mavlink


class Vehicle:
    """A vehicle's MAVLink server with signing on and its state file (a 'process')."""

    def __init__(self, state_path, key: bytes | None = KEY) -> None:
        self.vehicle = Commander(lambda p: make_controller("pid", PAPER, 0.01, None, p), 0.01)
        self.link = open_link("gcs", ("127.0.0.1", 0), None, key, 0)
        self.state = SigningState(state_path)
        self.said = self.state.restore([self.link.mav.signing])
        self.t = 1000.0
        self.server = MavlinkServer(self.vehicle, [self.link], clock=lambda: self.t,
                                    signing_state=self.state)
        self.port = self.link.sock.getsockname()[1]

    def take(self) -> int:
        """Read what arrived; the frames refused so far."""
        self.server.receive(self.link)
        return self.link.counters.rejected

    def stop(self) -> None:
        self.server.save_signing(force=True)
        self.link.sock.close()


def _sender(key: bytes | None = KEY):
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    mav = M.MAVLink(None, srcSystem=255, srcComponent=190)
    if key is not None:
        mav.signing.secret_key = key
        mav.signing.sign_outgoing = True
        mav.signing.timestamp = signing_clock_now()
    return sock, mav


def _wait(v: Vehicle) -> None:
    """Until a datagram waits on the vehicle's socket (loopback: at once)."""
    import select

    select.select([v.link.sock], [], [], 0.5)


def test_a_signed_frame_from_before_a_restart_is_refused_after_it(tmp_path):
    state = tmp_path / "signing.json"
    first = Vehicle(state)
    assert "none yet" in first.said
    sock, mav = _sender()
    frame = M.MAVLink_command_long_message(1, 1, M.MAV_CMD_COMPONENT_ARM_DISARM, 0, 0, 0, 0,
                                           0, 0, 0, 0).pack(mav)
    later = M.MAVLink_ping_message(1, 1, 0, 0).pack(mav)
    sock.sendto(frame, ("127.0.0.1", first.port))
    sock.sendto(later, ("127.0.0.1", first.port))
    _wait(first)
    assert first.take() == 0 and first.link.counters.frames == 2  # both taken
    first.stop()
    assert state.stat().st_mode & 0o777 == 0o600

    second = Vehicle(state)  # the restart
    assert "1 stream(s), clock restored" in second.said
    sock.sendto(frame, ("127.0.0.1", second.port))  # the captured frame, replayed
    _wait(second)
    assert second.take() == 1 and second.link.counters.frames == 0
    fresh = M.MAVLink_ping_message(2, 2, 0, 0).pack(mav)  # the real sender goes on
    sock.sendto(fresh, ("127.0.0.1", second.port))
    _wait(second)
    assert second.take() == 1 and second.link.counters.frames == 1
    assert second.link.mav.signing.timestamp > first.link.mav.signing.timestamp - 1
    second.stop()

    without = Vehicle(tmp_path / "other.json")  # no state: the replay gets through
    sock.sendto(frame, ("127.0.0.1", without.port))
    _wait(without)
    assert without.take() == 0 and without.link.counters.frames == 1
    without.stop()
    sock.close()


def test_setup_signing_only_over_a_signed_link_or_from_this_machine(tmp_path):
    v = Vehicle(tmp_path / "s.json", key=None)
    said: list[str] = []
    v.server.send_text = lambda link, severity, text, address=None: said.append(text)
    setup = M.MAVLink_setup_signing_message(1, 1, list(KEY), signing_clock_now())
    handler = v.server.handlers["SETUP_SIGNING"]
    handler(v.link, ("192.0.2.7", 14550), setup, v.t)  # unsigned, from another machine
    assert v.link.mav.signing.secret_key is None
    assert said[-1] == "SETUP_SIGNING refused: only over a signed link or from this machine"
    handler(v.link, ("127.0.0.1", 14550), setup, v.t)  # from this machine
    assert v.link.mav.signing.secret_key == KEY and v.link.mav.signing.sign_outgoing
    assert said[-1].startswith("signing on")
    # Signed now: an unsigned frame is refused before any handler.
    sock, mav = _sender(key=None)
    sock.sendto(M.MAVLink_ping_message(1, 1, 0, 0).pack(mav), ("127.0.0.1", v.port))
    _wait(v)
    assert v.take() == 1
    # Over the signed link, from anywhere: an all-zero key turns signing off.
    handler(v.link, ("192.0.2.7", 14550), M.MAVLink_setup_signing_message(
        1, 1, [0] * 32, 0), v.t)
    assert v.link.mav.signing.secret_key is None and said[-1].startswith("signing off")
    sock.close()
    v.stop()


@pytest.mark.parametrize("address, local", [
    (("127.0.0.1", 1), True), (("127.5.5.5", 1), True), (("::1", 1), True),
    (("192.168.1.2", 1), False), (("10.0.0.1", 1), False), (("not-an-ip", 1), False)])
def test_local_addresses(address, local):
    assert is_local(address) is local


def test_a_damaged_state_file_starts_without_it(tmp_path):
    path = tmp_path / "s.json"
    path.write_text("{not json")
    v = Vehicle(path)
    assert "unreadable" in v.said
    v.stop()


def test_setup_signing_with_a_timestamp_no_frame_carries_is_refused(tmp_path):
    v = Vehicle(tmp_path / "signing.json", key=None)
    handler = v.server.handlers["SETUP_SIGNING"]
    said = []
    v.server.send_text = lambda _link, _severity, text, _address=None: said.append(text)
    handler(v.link, ("127.0.0.1", 14550), M.MAVLink_setup_signing_message(
        1, 1, list(KEY), 2**64 - 1), 0.0)
    assert v.link.mav.signing.secret_key is None  # nothing changed
    assert said == ["SETUP_SIGNING refused: initial_timestamp 18446744073709551615 is not "
                    "a 48-bit signing timestamp"]
    v.stop()
