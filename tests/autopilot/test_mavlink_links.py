"""The vehicle's ground links under hostile traffic, in process: real UDP sockets on
loopback, a real MavlinkServer, an injected link clock. What each datagram costs, who
becomes a telemetry peer, what is refused, and how drops are made visible."""

from __future__ import annotations

import random
import socket
import time

import numpy as np
import pytest

from autopilot.commander.commander import Commander
from autopilot.control.factory import make_controller
from autopilot.mavlink.link import open_link
from autopilot.mavlink.server import (
    DROP_WARNING_S,
    HEARTBEAT_SHED_S,
    PEER_FORGET_S,
    PEER_SILENT_S,
    MavlinkServer,
    decode_datagram,
)
from contracts.airframe import PAPER
from contracts.mavlink import mavlink, new_mavlink

KEY = bytes(range(32))


class Clock:
    def __init__(self) -> None:
        self.t = 1000.0

    def __call__(self) -> float:
        return self.t


class Tool:
    """A client socket of its own (its own source port) with its own system id."""

    def __init__(self, port: int, sysid: int = 245, key: bytes | None = None) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.5)
        self.address = self.sock.getsockname()
        self.vehicle = ("127.0.0.1", port)
        self.mav = new_mavlink(sysid, 190)
        if key is not None:
            self.mav.signing.secret_key = key
            self.mav.signing.sign_outgoing = True
            self.mav.signing.timestamp = int((time.time() - 1420070400) * 100000)

    def send(self, msg) -> None:
        self.sock.sendto(msg.pack(self.mav), self.vehicle)

    def raw(self, data: bytes) -> None:
        self.sock.sendto(data, self.vehicle)

    def heartbeat(self) -> None:
        self.send(mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_GCS,
                                                    mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3))

    def param_request(self, target: int = 1) -> None:
        self.send(mavlink.MAVLink_param_request_read_message(target, 1, b"MPC_XY_VEL_MAX", -1))

    def received(self) -> list:
        parser = new_mavlink(self.mav.srcSystem, 190)
        if self.mav.signing.secret_key is not None:
            parser.signing.secret_key = self.mav.signing.secret_key
        out = []
        self.sock.setblocking(False)
        try:
            while True:
                out += parser.parse_buffer(self.sock.recv(65535)) or []
        except BlockingIOError:
            pass
        finally:
            self.sock.settimeout(0.5)
        return out

    def close(self) -> None:
        self.sock.close()


def _settle() -> None:
    time.sleep(0.02)  # loopback delivery


@pytest.fixture
def station():
    clock = Clock()
    vehicle = Commander(lambda p: make_controller("pid", PAPER, 0.01, None, p), 0.01)
    vehicle.sample(0.0, np.zeros(12))
    links = [open_link("gcs", ("127.0.0.1", 0), None, None, 0)]
    ground = MavlinkServer(vehicle, links, clock=clock, max_peers=2)
    tools: list[Tool] = []

    def tool(**kwargs) -> Tool:
        t = Tool(links[0].sock.getsockname()[1], **kwargs)
        tools.append(t)
        return t

    yield ground, links[0], clock, tool
    for t in tools:
        t.close()
    links[0].sock.close()


def test_garbage_is_refused_at_its_first_byte_and_cannot_spoil_the_next_frame(station):
    ground, link, _clock, tool = station
    t = tool()
    rng = random.Random(3)
    for _ in range(200):
        t.raw(rng.randbytes(rng.randint(1, 280)))
    # A frame start with a length that runs past the datagram: pymavlink's stream parser
    # would keep it and glue the next datagram on; here each datagram stands alone.
    t.raw(bytes([0xFD, 200, 0, 0, 0, 1, 1, 0, 0, 0]))
    t.param_request()
    _settle()
    assert ground.receive(link) == 202
    c = link.counters
    assert (c.datagrams, c.rejected, c.frames) == (202, 201, 1)
    assert [m.get_type() for m in t.received()] == ["PARAM_VALUE"]
    assert list(link.peers) == [t.address]


def test_a_read_is_bounded_and_leaves_the_rest_in_the_kernel(station):
    ground, link, _clock, tool = station
    t = tool()
    for _ in range(100):
        t.raw(b"\x00" * 20)
    _settle()
    assert ground.receive(link, max_datagrams=30) == 30
    assert ground.receive(link, budget_s=0.0) == 8  # a zero budget: one batch of 8
    assert ground.receive(link) == 62
    assert link.counters.datagrams == 100


def test_kernel_drops_are_counted_exactly(station):
    ground, link, _clock, tool = station
    link.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4096)  # a tiny buffer
    t = tool()
    for _ in range(500):
        t.raw(b"\x00" * 100)
    _settle()
    ground.receive(link)
    link.read_kernel_drops()
    c = link.counters
    assert c.kernel_drops > 0
    assert c.datagrams + c.kernel_drops == 500  # loopback loses nothing else
    assert link.lost() == (500, c.kernel_drops + c.rejected)


def test_heartbeats_from_one_address_are_decoded_once_per_shed_interval(station):
    ground, link, clock, tool = station
    t = tool()
    for _ in range(50):
        t.heartbeat()
    _settle()
    ground.receive(link)
    assert (link.counters.frames, link.counters.shed) == (1, 49)
    clock.t += HEARTBEAT_SHED_S
    t.heartbeat()
    _settle()
    ground.receive(link)
    assert link.counters.frames == 2


def test_only_valid_frames_for_us_make_peers_and_the_table_is_bounded(station):
    ground, link, clock, tool = station
    other = tool()
    other.param_request(target=7)  # another system's request
    bad_crc = bytearray(mavlink.MAVLink_heartbeat_message(6, 8, 0, 0, 0, 3).pack(new_mavlink(9, 1)))
    bad_crc[-1] ^= 0xFF
    other.raw(bytes(bad_crc))
    _settle()
    ground.receive(link)
    assert link.peers == {} and link.counters.not_for_us == 1 and link.counters.rejected == 1
    assert other.received() == []  # nothing answered for system 7

    a, b, c = tool(sysid=201), tool(sysid=202), tool(sysid=203)
    a.heartbeat()
    b.param_request()  # a tool: sends requests
    _settle()
    ground.receive(link)
    c.heartbeat()
    _settle()
    ground.receive(link)
    assert set(link.peers) == {a.address, b.address}  # full, both talking: c waits
    assert link.counters.peers_refused == 1

    clock.t += PEER_SILENT_S  # a and b silent
    c.heartbeat()
    _settle()
    ground.receive(link)
    # The heartbeat-only peer gives its place; the tool that asked keeps it.
    assert set(link.peers) == {b.address, c.address}

    clock.t += PEER_FORGET_S + 0.1
    ground.service()  # forgets peers silent for PEER_FORGET_S
    assert link.peers == {}


def test_signing_on_only_signed_frames_count_and_a_forgery_cannot_age_the_stream():
    clock = Clock()
    vehicle = Commander(lambda p: make_controller("pid", PAPER, 0.01, None, p), 0.01)
    link = open_link("gcs", ("127.0.0.1", 0), None, KEY, 0)
    ground = MavlinkServer(vehicle, [link], clock=clock)
    port = link.sock.getsockname()[1]
    honest, unsigned = Tool(port, key=KEY), Tool(port, sysid=246)
    forger = Tool(port, key=bytes(32))  # the wrong key
    try:
        unsigned.param_request()
        # Same stream (link id 0, 245/190) as the honest tool, a timestamp an hour ahead.
        forger.mav.srcSystem = 245
        forger.mav.signing.timestamp = honest.mav.signing.timestamp + 360_000_000
        forger.param_request()
        _settle()
        ground.receive(link)
        assert link.peers == {} and link.counters.rejected == 2
        honest.param_request()
        _settle()
        ground.receive(link)
        assert list(link.peers) == [honest.address]
        assert [m.get_type() for m in honest.received()] == ["PARAM_VALUE"]
        assert unsigned.received() == [] and forger.received() == []
    finally:
        for t in (honest, unsigned, forger):
            t.close()
        link.sock.close()


def test_drops_show_in_sys_status_and_one_statustext_a_minute(station):
    ground, link, clock, tool = station
    t = tool()
    t.heartbeat()
    _settle()
    ground.receive(link)
    ground.service()  # opens the drop window
    for _ in range(30):
        t.raw(b"garbage!")
    for _ in range(10):
        t.param_request()
    _settle()
    ground.receive(link)
    t.received()
    clock.t += 1.0
    ground.service()
    assert link.drop_rate == pytest.approx(30 / 40)
    texts = [m.text for m in t.received() if m.get_type() == "STATUSTEXT"]
    assert texts == ["gcs: 75% of datagrams lost (0 dropped, 30 bad)"]
    status = ground.telemetry(mavlink.MAVLINK_MSG_ID_SYS_STATUS)
    assert (status.drop_rate_comm, status.errors_comm) == (7500, 30)
    for _ in range(2):  # more drops within the minute: no second warning
        t.raw(b"garbage!")
        _settle()
        ground.receive(link)
        clock.t += 1.0
        ground.service()
    assert not [m for m in t.received() if m.get_type() == "STATUSTEXT"]
    clock.t += DROP_WARNING_S
    t.raw(b"garbage!")
    _settle()
    ground.receive(link)
    ground.service()
    assert [m.get_type() for m in t.received()].count("STATUSTEXT") == 1


def test_decode_datagram_takes_whole_frames_only():
    mav = new_mavlink(1, 1)
    hb = mavlink.MAVLink_heartbeat_message(6, 8, 0, 0, 0, 3).pack(new_mavlink(9, 1))
    assert [m.get_type() for m in decode_datagram(mav, hb + hb)] == ["HEARTBEAT"] * 2
    assert decode_datagram(mav, hb[:-1]) is None
    assert decode_datagram(mav, hb + b"\x00") is None
    assert decode_datagram(mav, b"") is None
    unknown = bytearray(hb)
    unknown[7] = 0xEE  # a message id pymavlink does not know: no CRC extra to trust
    # ... comes back as unknown (the server skips and counts it), the frames beside it kept
    assert [m.get_type() for m in decode_datagram(mav, hb + bytes(unknown) + hb)] == [
        "HEARTBEAT", "UNKNOWN_238", "HEARTBEAT"]


def _signed_unknown(key: bytes, timestamp: int) -> bytes:
    """A signed frame of message id 0xEEEE (unknown to pymavlink), signed with ``key``."""
    import hashlib
    import struct

    payload = b"\x01\x02\x03"
    header = bytes([0xFD, len(payload), 1, 0, 7, 245, 190, 0xEE, 0xEE, 0])
    body = header + payload + b"\x00\x00" + bytes([0]) + struct.pack("<Q", timestamp)[:6]
    return body + hashlib.sha256(key + body).digest()[:6]


def test_unknown_messages_are_skipped_and_counted_signed_or_not(station):
    ground, link, _clock, tool = station
    t = tool()
    hb = mavlink.MAVLink_heartbeat_message(6, 8, 0, 0, 0, 3).pack(new_mavlink(9, 1))
    unknown = bytearray(hb)
    unknown[7] = 0xEE
    request = mavlink.MAVLink_param_request_read_message(1, 1, b"MPC_XY_VEL_MAX", -1)
    t.raw(bytes(unknown) + request.pack(t.mav))
    _settle()
    ground.receive(link)
    assert (link.counters.unknown, link.counters.rejected, link.counters.frames) == (1, 0, 1)
    assert [m.get_type() for m in t.received()] == ["PARAM_VALUE"]  # the frame beside it

    signed = new_mavlink(1, 1)
    signed.signing.secret_key = KEY
    now = int((time.time() - 1420070400) * 100000)
    good = _signed_unknown(KEY, now)
    assert [m.get_type() for m in decode_datagram(signed, good)] == ["UNKNOWN_61166"]
    assert signed.signing.stream_timestamps[(0, 245, 190)] == now
    # A forged one (wrong key, an hour ahead) is refused and does not age the stream.
    assert decode_datagram(signed, _signed_unknown(bytes(32), now + 360_000_000)) is None
    assert signed.signing.stream_timestamps[(0, 245, 190)] == now
    assert decode_datagram(signed, hb) is None  # unsigned: refused as before


def test_max_peers_is_checked():
    vehicle = Commander(lambda p: make_controller("pid", PAPER, 0.01, None, p), 0.01)
    with pytest.raises(ValueError, match="max peers"):
        MavlinkServer(vehicle, [], max_peers=-1)
