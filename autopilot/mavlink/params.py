"""The MAVLink parameter protocol over the vehicle's parameters (PARAM_REQUEST_LIST /
READ, PARAM_SET, PARAM_VALUE), and the NAK that sends tools to it instead of FTP."""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING

from autopilot.parameters import PARAMETER_SPECS, PARAMETERS
from autopilot.refusal import RefusedError
from contracts.mavlink import mavlink

if TYPE_CHECKING:
    from autopilot.mavlink.link import GroundLink, ServerLink

PARAM_COUNT = len(PARAMETERS)
PARAM_INDEX = {spec.name: i for i, spec in enumerate(PARAMETERS)}
assert set(PARAMETER_SPECS) == set(PARAM_INDEX)
FTP_NAK, FTP_ERROR_UNSUPPORTED = 129, 4


class ParameterProtocol:
    def __init__(self, server: ServerLink) -> None:
        self.server = server

    def handlers(self) -> dict[str, Callable]:
        return {"PARAM_REQUEST_LIST": self.on_param_request_list,
                "PARAM_REQUEST_READ": self.on_param_request_read,
                "PARAM_SET": self.on_param_set,
                "FILE_TRANSFER_PROTOCOL": self.on_file_transfer_protocol}

    def param_value(self, name: str) -> mavlink.MAVLink_param_value_message:
        return mavlink.MAVLink_param_value_message(
            name.encode(), float(self.server.vehicle.parameters[name]),
            mavlink.MAV_PARAM_TYPE_REAL32, PARAM_COUNT, PARAM_INDEX[name])

    def _say(self, link: GroundLink, address, text: str) -> None:
        self.server.send_text(link, 4, text, address)

    def on_param_request_list(self, link: GroundLink, address, msg, now: float) -> None:
        for spec in PARAMETERS:
            self.server.send(link, self.param_value(spec.name), address)

    def on_param_request_read(self, link: GroundLink, address, msg, now: float) -> None:
        name = msg.param_id.rstrip("\x00") if msg.param_index < 0 else (
            PARAMETERS[msg.param_index].name if msg.param_index < PARAM_COUNT else "")
        if name not in PARAM_INDEX:
            self._say(link, address, f"unknown parameter {name or msg.param_index}")
            return
        self.server.send(link, self.param_value(name), address)

    def on_param_set(self, link: GroundLink, address, msg, now: float) -> None:
        name = msg.param_id.rstrip("\x00")
        if name not in PARAM_INDEX:
            self._say(link, address, f"unknown parameter {name}")
            return
        try:
            self.server.vehicle.set_parameter(name, msg.param_value)
        except RefusedError as exc:
            self._say(link, address, f"{name}: {exc}")
        # PARAM_VALUE either way, on every link: tools learn the value in force.
        value = self.param_value(name)
        for target_link in self.server.links:
            self.server.send(target_link, value)

    def on_file_transfer_protocol(self, link: GroundLink, address, msg, now: float) -> None:
        # No MAVLink FTP: a NAK ("unsupported") so tools fall back to the parameter
        # protocol at once.
        payload = bytes(msg.payload)
        seq = (int.from_bytes(payload[0:2], "little") + 1) % 65536  # a reply is request + 1
        nak = bytearray(251)
        nak[0:2] = seq.to_bytes(2, "little")
        nak[2] = payload[2]  # session
        nak[3] = FTP_NAK
        nak[4] = 1  # data size
        nak[5] = payload[3] if len(payload) > 3 else 0  # req_opcode
        nak[12] = FTP_ERROR_UNSUPPORTED
        self.server.send(link, mavlink.MAVLink_file_transfer_protocol_message(
            0, msg.get_srcSystem(), msg.get_srcComponent(), list(nak)), address)
