"""The MAVLink parameter protocol over the vehicle's parameters (PARAM_REQUEST_LIST /
READ, PARAM_SET, PARAM_VALUE), and the NAK that sends tools to it instead of FTP.

Each flavour answers as its autopilot does:

* PX4: the internal names, INT32 or REAL32 as PX4 declares each; an INT32 travels as the
  integer's four bytes in the float field (byte-wise encoding, declared in
  AUTOPILOT_VERSION); a PARAM_SET whose type differs from the parameter's changes
  nothing and gets no PARAM_VALUE ("param types mismatch", as PX4's mavlink_parameters);
  a set is answered to the setter, then the value goes to every link.
* ArduPilot: Copter's names, units and types (autopilot/copter_parameters.py), values
  C-cast into the float field; a PARAM_SET is cast to the parameter's own type whatever
  type it says, answered with PARAM_VALUE (index -1) on every link; unknown names are
  ignored without a reply, as GCS_Param.cpp does.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable
from typing import TYPE_CHECKING

from autopilot.copter_parameters import (
    ardupilot_parameters,
    cast,
    px4_parameters,
)
from autopilot.parameters import PARAMETER_SPECS
from autopilot.refusal import RefusedError
from contracts.mavlink import mavlink

if TYPE_CHECKING:
    from autopilot.copter_parameters import CopterParam
    from autopilot.mavlink.link import GroundLink, ServerLink

PX4_NAMES = px4_parameters()
PARAM_COUNT = len(PX4_NAMES)  # the PX4 flavour's
PARAM_INDEX = {name: i for i, name in enumerate(PX4_NAMES)}
FTP_NAK, FTP_ERROR_UNSUPPORTED = 129, 4
NO_INDEX = 65535  # Copter's param_index -1 in PARAM_VALUE's uint16 field
MAV_TYPES = {"INT8": mavlink.MAV_PARAM_TYPE_INT8, "INT16": mavlink.MAV_PARAM_TYPE_INT16,
             "INT32": mavlink.MAV_PARAM_TYPE_INT32, "REAL32": mavlink.MAV_PARAM_TYPE_REAL32}


def int32_as_float(value: int) -> float:
    """The float whose four bytes are the INT32 ``value`` (PX4's byte-wise encoding)."""
    return struct.unpack("<f", struct.pack("<i", value))[0]


def float_as_int32(value: float) -> int:
    """The INT32 carried in a byte-wise encoded float field."""
    return struct.unpack("<i", struct.pack("<f", value))[0]


class ParameterProtocol:
    def __init__(self, server: ServerLink) -> None:
        self.server = server
        self.ardupilot = server.flavour == "ardupilot"
        copter = ardupilot_parameters()
        self.copter: dict[str, CopterParam] = {p.name: p for p in copter}
        # What this flavour lists, in order.
        self.names: tuple[str, ...] = tuple(self.copter) if self.ardupilot else PX4_NAMES
        self.index = {name: i for i, name in enumerate(self.names)}
        # Copter parameters with nothing in the vehicle that obeys them: kept here.
        self.stored = {p.name: p.default for p in copter if p.internal is None}

    def handlers(self) -> dict[str, Callable]:
        return {"PARAM_REQUEST_LIST": self.on_param_request_list,
                "PARAM_REQUEST_READ": self.on_param_request_read,
                "PARAM_SET": self.on_param_set,
                "FILE_TRANSFER_PROTOCOL": self.on_file_transfer_protocol}

    # -- values as the flavour shows them --------------------------------------------------
    def value(self, name: str) -> float:
        """``name``'s value in this flavour's units (Copter's in the ArduPilot flavour)."""
        if not self.ardupilot:
            return float(self.server.vehicle.parameters[name])
        p = self.copter[name]
        if p.internal is None:
            return self.stored[name]
        return cast(p.ap_type, p.from_internal(self.server.vehicle.parameters[p.internal]))

    def param_value(self, name: str, index: int | None = None
                    ) -> mavlink.MAVLink_param_value_message:
        value = self.value(name)
        if self.ardupilot:
            kind = MAV_TYPES[self.copter[name].ap_type]
        elif PARAMETER_SPECS[name].integer:
            kind, value = mavlink.MAV_PARAM_TYPE_INT32, int32_as_float(int(value))
        else:
            kind = mavlink.MAV_PARAM_TYPE_REAL32
        return mavlink.MAVLink_param_value_message(
            name.encode(), value, kind, len(self.names),
            self.index[name] if index is None else index)

    def _say(self, link: GroundLink, address, text: str) -> None:
        self.server.send_text(link, 4, text, address)

    # -- handlers --------------------------------------------------------------------------
    def on_param_request_list(self, link: GroundLink, address, msg, now: float) -> None:
        for name in self.names:
            self.server.send(link, self.param_value(name), address)

    def on_param_request_read(self, link: GroundLink, address, msg, now: float) -> None:
        name = msg.param_id.rstrip("\x00") if msg.param_index < 0 else (
            self.names[msg.param_index] if msg.param_index < len(self.names) else "")
        if name not in self.index:
            if not self.ardupilot:  # Copter drops it without a word
                self._say(link, address, f"unknown parameter {name or msg.param_index}")
            return
        # Copter echoes the index asked (-1 for a read by name); PX4 gives the index.
        index = (msg.param_index % 65536) if self.ardupilot else None
        self.server.send(link, self.param_value(name, index), address)

    def on_param_set(self, link: GroundLink, address, msg, now: float) -> None:
        name = msg.param_id.rstrip("\x00")
        if name not in self.index:
            if not self.ardupilot:  # Copter ignores an unknown name without a word
                self._say(link, address, f"unknown parameter {name}")
            return
        if self.ardupilot:
            self._set_copter(link, address, name, msg.param_value)
            # Copter's echo: on every link, index -1.
            value = self.param_value(name, NO_INDEX)
        else:
            if not self._set_px4(link, address, name, msg):
                return
            value = self.param_value(name)
            # PX4 answers the setter at once, then sends the changed parameter on every
            # link (send_untransmitted): MAVSDK's parameter subscriptions (the failure
            # plugin's SYS_FAILURE_EN) learn of a change from that second one.
            self.server.send(link, value, address)
        # PARAM_VALUE on every link: tools learn the value in force.
        for target_link in self.server.links:
            self.server.send(target_link, value)

    def _set_px4(self, link: GroundLink, address, name: str, msg) -> bool:
        """Set as PX4 does; False when PX4 answers nothing (a type mismatch)."""
        integer = PARAMETER_SPECS[name].integer
        wanted = mavlink.MAV_PARAM_TYPE_INT32 if integer else mavlink.MAV_PARAM_TYPE_REAL32
        if msg.param_type != wanted:
            self._say(link, address, f"param types mismatch: {name}")
            return False
        value = float(float_as_int32(msg.param_value)) if integer else msg.param_value
        try:
            self.server.vehicle.set_parameter(name, value)
        except RefusedError as exc:
            self._say(link, address, f"{name}: {exc}")
        return True

    def _set_copter(self, link: GroundLink, address, name: str, sent: float) -> None:
        if not math.isfinite(sent):  # Copter keeps the value (AP_Param::set_float)
            return
        p = self.copter[name]
        value = cast(p.ap_type, sent)
        if p.internal is None:
            self.stored[name] = value
            return
        try:
            self.server.vehicle.set_parameter(p.internal, p.to_internal(value))
        except ValueError as exc:  # an enumeration number with no behaviour here
            self._say(link, address, f"Param write denied ({name}): {exc}")
        except RefusedError:  # said in Copter's units, not the internal ones
            spec = PARAMETER_SPECS[p.internal]
            whole = " (whole numbers)" if spec.integer else ""
            self._say(link, address, f"Param write denied ({name}): {value:g} is outside "
                      f"{spec.minimum * p.scale:g}..{spec.maximum * p.scale:g} "
                      f"{p.unit}{whole}".rstrip())

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
