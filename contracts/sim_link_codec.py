"""The simulator link's hot messages packed and parsed by precompiled layouts.

Why: each lockstep cycle the simulator packs HIL_GPS, HIL_SENSOR, HIL_STATE_QUATERNION and
ODOMETRY, the autopilot parses the ones it flies on and answers with HIL_ACTUATOR_CONTROLS,
which the simulator parses. pymavlink does that generically (a header object, a Python
trim loop, a message object built field by field on parsing): 4-15 us a message, a large
part of a cycle. Here each of those five messages has one ``struct.Struct`` of its whole
payload, built once from pymavlink's own metadata of the message (wire order, types,
array lengths, CRC extra), so the bytes are pymavlink's byte for byte.

* Packing (``pack_messages``, ``pack_message``, and ``pack_fields`` from a message's
  constructor arguments, without the message object): the payload in one struct call, its
  trailing zero bytes trimmed as MAVLink 2 (and pymavlink) trims them, the header from
  the link's MAVLink object (its ``seq``, ``srcSystem``, ``srcComponent``: pymavlink's
  pack reads ``seq`` and does not advance it) and the X.25 checksum (CRC-16/MCRF4XX over
  header and payload, then the message's CRC extra) by ``fastcrc``, the compiled CRC that
  pymavlink itself uses (0.13-0.16 us for 30-300 bytes, against 0.3-0.9 us numba-compiled
  and 2-18 us in Python; ``binascii.crc_hqx`` on bit-reversed bytes: 0.25-1.1 us).
  The autopilot's mirror streams (``PACKED_ONLY``) are packed the same way. A link that
  signs (``mav.signing.sign_outgoing``) and any other message are packed by pymavlink.
* Parsing (``parse_frames``): a whole MAVLink 2 frame of a known layout, unsigned, with
  no incompatibility flag, no longer than the layout and with a good checksum becomes a
  ``LinkMessage`` (a named tuple with the pymavlink message's field names, arrays as
  tuples, and ``get_type()``); its payload is zero-extended as MAVLink 2 receivers do.
  Every other frame, and any garbage, goes to the link's pymavlink parser in the order
  it came, so bad input is judged (BAD_DATA) exactly as before. A link that checks
  signatures (``mav.signing.secret_key``) parses everything with pymavlink.

tests/contracts/test_sim_link_codec.py cross-checks both directions against pymavlink.
"""

from __future__ import annotations

import inspect
import operator
import struct
from collections import namedtuple
from collections.abc import Iterable
from typing import Any

from fastcrc.crc16 import mcrf4xx
from pymavlink.dialects.v20 import common as mavlink

MAGIC_V2 = 0xFD
HEADER_BYTES = 10  # magic, length, incompat, compat, seq, sysid, compid, msgid (3 bytes)
CHECKSUM_BYTES = 2
# Header bytes 1-9, the part the checksum covers (the magic is not).
_HEADER_AFTER_MAGIC = struct.Struct("<BBBBBBHB")
_CHECKSUM = struct.Struct("<H")
_CRC_START = 0xFFFF


class LinkMessage(tuple):
    """Base of the light messages ``parse_frames`` gives: what a consumer of the
    pymavlink message reads (its fields by name, ``get_type()``), without its object."""

    __slots__ = ()
    msgname = ""

    def get_type(self) -> str:
        return self.msgname


class Layout:
    """One message's wire layout, from its pymavlink class: payload struct in wire order,
    CRC extra, where each field sits in the unpacked values."""

    def __init__(self, cls: type[mavlink.MAVLink_message]) -> None:
        if any(t == "char" for t in cls.fieldtypes):
            raise ValueError(f"{cls.msgname}: text fields are not laid out here")
        self.cls = cls
        self.msgid = cls.id
        self.msgname = cls.msgname
        # native_format: "<" then one struct code per field in wire order; array_lengths
        # (wire order) says how many of each (0: a scalar).
        codes = cls.native_format.decode()[1:]
        self.payload = struct.Struct("<" + "".join(
            f"{n}{code}" if n else code for code, n in zip(codes, cls.array_lengths,
                                                          strict=True)))
        assert self.payload.format == cls.unpacker.format, cls.msgname
        self.size_bytes = self.payload.size
        self._crc_extra = bytes((cls.crc_extra,))
        self._msgid_low, self._msgid_high = cls.id & 0xFFFF, cls.id >> 16
        # Packing: the fields in wire order, arrays spliced in flat (the last first, so
        # the earlier ones' indices stay put).
        self._wire_values = operator.attrgetter(*cls.ordered_fieldnames)
        self._wire_from_fields = operator.itemgetter(*map(cls.fieldnames.index,
                                                          cls.ordered_fieldnames))
        # The constructor's defaults (MAVLink 2 extension fields), for fields left out.
        self._defaults = tuple(p.default for p in list(
            inspect.signature(cls.__init__).parameters.values())[1:])
        self._arrays = [i for i, n in enumerate(cls.array_lengths) if n][::-1]
        # Parsing: each field (pymavlink's constructor order) as an index or a slice of
        # the flat unpacked values.
        starts = [0]
        for n in cls.array_lengths:
            starts.append(starts[-1] + max(n, 1))
        items = []
        for name in cls.fieldnames:
            wire = cls.ordered_fieldnames.index(name)
            n = cls.array_lengths[wire]
            items.append(slice(starts[wire], starts[wire] + n) if n else starts[wire])
        self._fields = operator.itemgetter(*items)
        self.message_type = type(cls.msgname, (namedtuple(cls.msgname, cls.fieldnames),
                                               LinkMessage),
                                 {"__slots__": (), "msgname": cls.msgname})

    def pack(self, msg: Any, mav: mavlink.MAVLink) -> bytes:
        """The frame pymavlink's ``msg.pack(mav)`` gives (``mav`` unsigned)."""
        return self._frame(list(self._wire_values(msg)), mav)

    def pack_fields(self, fields: tuple, mav: mavlink.MAVLink) -> bytes:
        """The frame of ``cls(*fields).pack(mav)``, without the message (``mav``
        unsigned)."""
        if len(fields) < len(self._defaults):
            missing = self._defaults[len(fields):]
            if inspect.Parameter.empty in missing:
                raise TypeError(f"{self.msgname} takes {len(self._defaults)} fields, got "
                                f"{len(fields)}")
            fields = (*fields, *missing)
        return self._frame(list(self._wire_from_fields(fields)), mav)

    def _frame(self, values: list, mav: mavlink.MAVLink) -> bytes:
        """The frame of the field values in wire order, arrays not yet spliced in."""
        for i in self._arrays:
            values[i:i + 1] = values[i]  # one of another length: struct.error
        payload = self.payload.pack(*values)
        payload = payload.rstrip(b"\0") or payload[:1]  # MAVLink 2 keeps at least a byte
        header = _HEADER_AFTER_MAGIC.pack(len(payload), 0, 0, mav.seq, mav.srcSystem,
                                          mav.srcComponent, self._msgid_low,
                                          self._msgid_high)
        crc = mcrf4xx(self._crc_extra, mcrf4xx(payload, mcrf4xx(header, _CRC_START)))
        return b"".join((b"\xfd", header, payload, _CHECKSUM.pack(crc)))

    def parse(self, frame: bytes) -> LinkMessage | None:
        """The message of one whole frame of this message id; None when it is not a plain
        MAVLink 2 frame of this layout with a good checksum (pymavlink judges those)."""
        length = frame[1]
        if frame[0] != MAGIC_V2 or frame[2] or length > self.size_bytes or \
                len(frame) != HEADER_BYTES + length + CHECKSUM_BYTES:
            return None
        end = HEADER_BYTES + length
        if mcrf4xx(self._crc_extra, mcrf4xx(frame[1:end], _CRC_START)) != \
                frame[end] | frame[end + 1] << 8:
            return None
        if length == self.size_bytes:
            values = self.payload.unpack_from(frame, HEADER_BYTES)
        else:  # trimmed by the sender: the missing bytes are zeros
            values = self.payload.unpack(frame[HEADER_BYTES:end].ljust(self.size_bytes, b"\0"))
        return tuple.__new__(self.message_type, self._fields(values))


# The simulator link's hot messages (PX4's simulator protocol), by message id.
LAYOUTS: dict[int, Layout] = {layout.msgid: layout for layout in map(Layout, (
    mavlink.MAVLink_hil_gps_message,
    mavlink.MAVLink_hil_sensor_message,
    mavlink.MAVLink_hil_state_quaternion_message,
    mavlink.MAVLink_odometry_message,
    mavlink.MAVLink_hil_actuator_controls_message,
))}
# Packed by a layout too, not parsed: the autopilot's log mirror of its sim-time telemetry
# streams (autopilot/process/telemetry.py), a few messages each 100 ms of sim time.
PACKED_ONLY = (mavlink.MAVLink_heartbeat_message, mavlink.MAVLink_attitude_message,
               mavlink.MAVLink_local_position_ned_message,
               mavlink.MAVLink_global_position_int_message)
_BY_CLASS = {layout.cls: layout for layout in (*LAYOUTS.values(), *map(Layout, PACKED_ONLY))}


def pack_message(msg: mavlink.MAVLink_message, mav: mavlink.MAVLink) -> bytes:
    """``msg.pack(mav)``, by its layout when it has one and ``mav`` does not sign."""
    layout = _BY_CLASS.get(type(msg))
    if layout is None or mav.signing.sign_outgoing:
        return msg.pack(mav)
    return layout.pack(msg, mav)


def pack_fields(cls: type[mavlink.MAVLink_message], fields: tuple,
                mav: mavlink.MAVLink) -> bytes:
    """``cls(*fields).pack(mav)`` for a message with a layout, without building the
    message unless ``mav`` signs (the simulator's samples, the autopilot's answer)."""
    if mav.signing.sign_outgoing:
        return cls(*fields).pack(mav)
    return _BY_CLASS[cls].pack_fields(fields, mav)


def pack_messages(msgs: Iterable[mavlink.MAVLink_message], mav: mavlink.MAVLink) -> bytes:
    """The frames of ``msgs`` end to end, as pymavlink packs them on ``mav``."""
    return b"".join([pack_message(m, mav) for m in msgs])


def parse_frames(frames: Iterable[tuple[int, bytes]], mav: mavlink.MAVLink) -> list:
    """The messages of ``frames`` (``split_frames``' ``(msgid, frame)``, garbage as msgid
    -1) in order: ``LinkMessage`` where a layout parses the frame, else what ``mav``'s
    pymavlink parser makes of it (BAD_DATA included). Frames that go to pymavlink
    together go in one buffer, as they would have without the layouts."""
    out: list = []
    slow: list[bytes] = []
    layouts = LAYOUTS if mav.signing.secret_key is None else {}
    for msgid, frame in frames:
        layout = layouts.get(msgid)
        msg = layout.parse(frame) if layout is not None else None
        if msg is None:
            slow.append(frame)
            continue
        if slow:
            out += mav.parse_buffer(b"".join(slow)) or []
            slow.clear()
        out.append(msg)
    if slow:
        out += mav.parse_buffer(b"".join(slow)) or []
    return out
