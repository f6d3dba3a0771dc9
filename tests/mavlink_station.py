"""A vehicle's MAVLink server on real loopback sockets with an injected clock, and a
pymavlink client on each link: what the tests of the vehicle's MAVLink protocols share
(the ``station`` and ``make_station`` fixtures in tests/conftest.py build it)."""

from __future__ import annotations

import math
import select
import socket

import numpy as np
from pymavlink.dialects.v20 import common as mavlink

from autopilot.commander.commander import Commander
from autopilot.control.factory import make_controller
from contracts.airframe import PAPER
from contracts.mavlink import DIALECTS, StatustextAssembler
from contracts.modes import FlightMode

M = mavlink
ACCEPTED = M.MAV_RESULT_ACCEPTED
ARM, REQUEST_MESSAGE = M.MAV_CMD_COMPONENT_ARM_DISARM, M.MAV_CMD_REQUEST_MESSAGE
T0 = 1000.0  # the link clock when the server starts
GROUND = np.zeros(12)
INT32_MAX = 2**31 - 1  # COMMAND_INT's "unused" x and y


def air(altitude_m: float = 2.5) -> np.ndarray:
    m = np.zeros(12)
    m[2] = -altitude_m
    return m


class Clock:
    """The link clock the server reads."""

    def __init__(self) -> None:
        self.t = T0

    def __call__(self) -> float:
        return self.t


def make_server(vehicle: Commander, links: list, clock: Clock, flavour: str = "px4"):
    """The one place the server is built (its class and module may be renamed)."""
    from autopilot.mavlink.server import MavlinkServer

    return MavlinkServer(vehicle, links, flavour, clock=clock)


def open_links(n: int, flavour: str = "px4") -> list:
    from autopilot.mavlink.link import open_link

    return [open_link(name, ("127.0.0.1", 0), None, None, i, flavour=flavour)
            for i, name in enumerate(("gcs", "api")[:n])]


class Client:
    """A ground tool: its own UDP socket and pymavlink encoder (system 255 by default).

    ``sync`` is the barrier: a PING goes out, the server reads everything waiting on the
    link, and what it sent us up to its PING answer is returned."""

    def __init__(self, station: Station, link, sysid: int = 255, compid: int = 190) -> None:
        self.station, self.link = station, link
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.address = self.sock.getsockname()
        self.vehicle_address = ("127.0.0.1", link.sock.getsockname()[1])
        dialect = DIALECTS[station.flavour]  # the vehicle's dialect, as a tool picks it
        self.mav = dialect.MAVLink(None, srcSystem=sysid, srcComponent=compid)
        self.parser = dialect.MAVLink(None, srcSystem=sysid, srcComponent=compid)
        self.parser.robust_parsing = True
        self.pings = 0

    def send(self, msg) -> None:
        self.sock.sendto(msg.pack(self.mav), self.vehicle_address)

    def heartbeat(self, kind: int = M.MAV_TYPE_GCS) -> None:
        self.send(M.MAVLink_heartbeat_message(kind, M.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3))

    def _read(self) -> list:
        out = []
        while select.select([self.sock], [], [], 0.0)[0]:
            out += self.parser.parse_buffer(self.sock.recv(65535)) or []
        return out

    def sync(self) -> list:
        self.pings += 1
        self.send(M.MAVLink_ping_message(self.pings, self.pings, 0, 0))
        got: list = []
        for _ in range(200):  # 2 s at most: loopback takes microseconds
            if select.select([self.link.sock], [], [], 0.01)[0]:
                self.station.server.receive(self.link)
            got += self._read()
            for i, msg in enumerate(got):
                if msg.get_type() == "PING" and msg.seq == self.pings:
                    return got[:i] + got[i + 1:]
        raise AssertionError("no answer to the barrier PING")

    def send_command(self, command: int, *params: float, kind: str = "long",
                     target: int = 1, frame: int = M.MAV_FRAME_GLOBAL) -> None:
        """COMMAND_LONG, or COMMAND_INT (params 5 and 6 as 1e-7 integers, 7 as z)."""
        p = [*params, *[0.0] * (7 - len(params))]
        if kind == "long":
            self.send(M.MAVLink_command_long_message(target, 1, command, 0, *p))
        else:
            x, y = (INT32_MAX if math.isnan(v) else round(v * 1e7) for v in p[4:6])
            self.send(M.MAVLink_command_int_message(
                target, 1, frame, command, 0, 0, *p[0:4], x, y, p[6]))

    def command(self, command: int, *params: float, kind: str = "long",
                target: int = 1, frame: int = M.MAV_FRAME_GLOBAL) -> tuple:
        """(COMMAND_ACK, everything else received with it)."""
        self.send_command(command, *params, kind=kind, target=target, frame=frame)
        msgs = self.sync()
        acks = [m for m in msgs if m.get_type() == "COMMAND_ACK"]
        assert len(acks) == (1 if target == 1 else 0), msgs
        if acks:
            assert acks[0].command == command
            # Acknowledged to the sender.
            assert (acks[0].target_system, acks[0].target_component) == (
                self.mav.srcSystem, self.mav.srcComponent)
        return (acks[0] if acks else None), [m for m in msgs if m.get_type() != "COMMAND_ACK"]

    def request(self, msg_id: int):
        """REQUEST_MESSAGE: the message, which comes after an ACCEPTED ACK."""
        ack, others = self.command(REQUEST_MESSAGE, msg_id)
        assert ack.result == ACCEPTED
        (msg,) = others
        return msg

    def result(self, command: int, *params: float, **kwargs) -> tuple[int, list[str]]:
        """The ACK's result and the STATUSTEXT that came with it."""
        ack, others = self.command(command, *params, **kwargs)
        return ack.result, texts(others)

    def close(self) -> None:
        self.sock.close()


class Station:
    """A vehicle with its server, the links, the clock and a client on the first link."""

    def __init__(self, n_links: int = 1, flavour: str = "px4", **parameters) -> None:
        self.clock = Clock()
        self.flavour = flavour
        self.vehicle = Commander(lambda p: make_controller("pid", PAPER, 0.01, None, p), 0.01,
                               parameters, flavour=flavour)
        self.links = open_links(n_links, flavour)
        self.server = make_server(self.vehicle, self.links, self.clock, flavour)
        self.clients: list[Client] = []
        self.client = self.new_client()

    def new_client(self, link_index: int = 0, **kwargs) -> Client:
        client = Client(self, self.links[link_index], **kwargs)
        self.clients.append(client)
        return client

    def at(self, t: float) -> None:
        self.clock.t = t

    def service(self, t: float | None = None) -> None:
        if t is not None:
            self.clock.t = t
        self.server.service()

    def state_up(self, measurement: np.ndarray = GROUND, sim_t: float = 0.0) -> None:
        self.vehicle.sample(sim_t, measurement)

    def flying(self) -> None:
        """Armed (through the server) and in the air; queued STATUSTEXT sent and read.
        A Copter arms in GUIDED (its boot mode, STABILIZE, needs RC sticks to arm)."""
        self.state_up()
        if self.flavour == "ardupilot" and self.vehicle.mode is FlightMode.STABILIZED:
            self.vehicle.set_mode(FlightMode.GUIDED, self.clock.t)
        assert self.client.result(ARM, 1)[0] == ACCEPTED
        self.state_up(air(), 0.01)
        assert self.vehicle.armed and not self.vehicle.landed
        self.server.service()
        self.client.sync()

    def close(self) -> None:
        for client in self.clients:
            client.close()
        for link in self.links:
            link.sock.close()


def texts(msgs: list) -> list[str]:
    """The whole texts, chunks reassembled as QGroundControl and MAVSDK do."""
    assembler = StatustextAssembler()
    return [t for m in msgs if m.get_type() == "STATUSTEXT"
            and (t := assembler.add(m)) is not None]


def of_type(msgs: list, kind: str) -> list:
    return [m for m in msgs if m.get_type() == kind]
