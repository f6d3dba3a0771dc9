"""MAVLink 2 frames packed and parsed in compiled code, for the messages a step sends or
reads every period.

Why: the simulator link carries four or five frames each period each way; built and read
by pymavlink (or by ``struct`` from Python) they cost more than the plant and the
controller together. Here a message is a ``FrameLayout`` made once from pymavlink's own
metadata of it (wire order, types, array lengths, CRC extra), and its field values travel
as two flat arrays in wire order, ``ints`` (int64; a uint64 above 2**63 as its two's
complement, the same bytes) and ``floats`` (float64), each field in the one its type
says. The compiled functions then work on bytes in buffers allocated once:

* ``pack_frame``: the payload, trailing zero bytes trimmed as MAVLink 2 (and pymavlink)
  trims them but one, the header (sequence, system, component, message id) and the X.25
  checksum with the message's CRC extra. A float32 field of a value beyond float32's
  range is written as infinity (pymavlink's ``struct`` would raise).
* ``frame_length`` / ``checked_frame``: where a frame ends, and whether it is a plain
  MAVLink 2 frame of a layout (no incompatibility flag, so unsigned; not longer than the
  payload; a good checksum). Anything else is for pymavlink to judge, as it judges it.
* ``unpack_payload``: the fields of a payload, zero-extended as MAVLink 2 receivers do.

Signing is pymavlink's: a link that signs or checks signatures packs and parses with it.
tests/contracts/test_mavlink_codec.py cross-checks everything against pymavlink over
randomized fields, byte for byte.
"""

from __future__ import annotations

import operator

import numpy as np
from numba import njit
from pymavlink.dialects.v20 import common as mavlink

from contracts.mavlink import frame_msgid, frame_size

MAGIC_V2 = 0xFD
HEADER_BYTES = 10  # magic, length, incompat, compat, seq, sysid, compid, msgid (3 bytes)
CHECKSUM_BYTES = 2
MAX_PAYLOAD_BYTES = 255
MAX_FRAME_BYTES = HEADER_BYTES + MAX_PAYLOAD_BYTES + CHECKSUM_BYTES + 13  # signed: + 13

# Wire types by struct code: their numbers here, and their sizes.
U8, I8, U16, I16, U32, I32, U64, I64, F32, F64 = range(10)
_CODE_OF = {"B": U8, "b": I8, "H": U16, "h": I16, "I": U32, "i": I32, "Q": U64, "q": I64,
            "f": F32, "d": F64}
TYPE_BYTES = np.array([1, 1, 2, 2, 4, 4, 8, 8, 4, 8], dtype=np.int64)


class FrameLayout:
    """One message's wire layout, from its pymavlink class: each flat field's (arrays
    spliced in) type code and byte offset in wire order, and the payload's size."""

    def __init__(self, cls: type[mavlink.MAVLink_message]) -> None:
        codes = cls.native_format.decode()[1:]
        if any(c not in _CODE_OF for c in codes):
            raise ValueError(f"{cls.msgname}: text fields are not laid out here")
        self.cls = cls
        self.msgid = cls.id
        self.msgname = cls.msgname
        self.crc_extra = cls.crc_extra
        flat: list[int] = []
        # Each constructor field's place among the flat values: an index, or a slice.
        starts: dict[str, slice | int] = {}
        for name, code, n in zip(cls.ordered_fieldnames, codes, cls.array_lengths,
                                 strict=True):
            starts[name] = slice(len(flat), len(flat) + n) if n else len(flat)
            flat += [_CODE_OF[code]] * max(n, 1)
        self.codes = np.array(flat, dtype=np.int64)
        sizes = TYPE_BYTES[self.codes]
        self.offsets = np.concatenate(([0], np.cumsum(sizes)[:-1])).astype(np.int64)
        self.payload_bytes = int(sizes.sum())
        self.places = [starts[name] for name in cls.fieldnames]
        self._starts = {name: p.start if isinstance(p, slice) else p
                        for name, p in starts.items()}
        self.is_float = self.codes >= F32
        self._float_at = np.flatnonzero(self.is_float).tolist()
        self._int_at = np.flatnonzero(~self.is_float).tolist()
        # The constructor's fields in wire order (arrays whole), from the constructor's
        # arguments or from a message.
        self._wire_from_fields = operator.itemgetter(*map(cls.fieldnames.index,
                                                          cls.ordered_fieldnames))
        self._wire_of_message = operator.attrgetter(*cls.ordered_fieldnames)

    def index(self, name: str) -> int:
        """Where a field (an array's first element) sits among the flat values."""
        return self._starts[name]

    def values(self, fields: tuple) -> tuple[np.ndarray, np.ndarray]:
        """(ints, floats) of a message's constructor arguments."""
        return self._flat_values(self._wire_from_fields(fields))

    def _flat_values(self, wire: tuple) -> tuple[np.ndarray, np.ndarray]:
        """(ints, floats) of the fields in wire order, arrays whole."""
        flat: list = []
        for value in wire:
            if isinstance(value, (list, tuple)):
                flat += value
            else:
                flat.append(value)
        if len(flat) != len(self.codes):
            raise ValueError(f"{self.msgname}: {len(flat)} values for {len(self.codes)}")
        ints = np.zeros(len(self.codes), dtype=np.int64)
        floats = np.zeros(len(self.codes))
        floats[self._float_at] = [flat[i] for i in self._float_at]
        ints[self._int_at] = [int(flat[i]) - (1 << 64) if int(flat[i]) >= 1 << 63
                              else int(flat[i]) for i in self._int_at]
        return ints, floats

    def fields(self, ints: np.ndarray, floats: np.ndarray) -> tuple:
        """The constructor arguments of flat values (unsigned integers as unsigned)."""
        flat = [float(floats[i]) if self.is_float[i] else
                int(ints[i]) & 0xFFFFFFFFFFFFFFFF if self.codes[i] == U64 else int(ints[i])
                for i in range(len(self.codes))]
        return tuple(flat[p] if isinstance(p, slice) else flat[p] for p in self.places)

    def pack(self, ints: np.ndarray, floats: np.ndarray, seq: int, sysid: int,
             compid: int) -> bytes:
        """The frame of flat values (for tools and tests; steps call ``pack_frame``)."""
        out = np.empty(MAX_FRAME_BYTES, dtype=np.uint8)
        end = pack_frame(out, 0, ints, floats, self.codes, self.offsets, self.msgid,
                         self.crc_extra, seq, sysid, compid)
        return out[:end].tobytes()

    def pack_message(self, msg: mavlink.MAVLink_message, mav: mavlink.MAVLink) -> bytes:
        """``msg.pack(mav)`` (``mav`` unsigned), from the message's fields."""
        return self.pack(*self._flat_values(self._wire_of_message(msg)), mav.seq,
                         mav.srcSystem, mav.srcComponent)

    def pack_fields(self, fields: tuple, mav: mavlink.MAVLink) -> bytes:
        """The frame of ``cls(*fields).pack(mav)`` (``mav`` unsigned), without the
        message."""
        return self.pack(*self.values(fields), mav.seq, mav.srcSystem, mav.srcComponent)

    def unpack(self, frame: bytes) -> tuple[np.ndarray, np.ndarray] | None:
        """The flat values of one whole frame; None unless it is a plain MAVLink 2 frame
        of this layout with a good checksum (a frame for pymavlink to judge)."""
        buf = np.frombuffer(frame, dtype=np.uint8)
        if len(buf) < HEADER_BYTES + CHECKSUM_BYTES or frame_length(buf, 0) != len(buf) or \
                msgid_at(buf, 0) != self.msgid or \
                not checked_frame(buf, 0, self.crc_extra, self.payload_bytes):
            return None
        ints = np.zeros(len(self.codes), dtype=np.int64)
        floats = np.zeros(len(self.codes))
        unpack_payload(buf, HEADER_BYTES, buf[1], self.codes, self.offsets, ints, floats)
        return ints, floats


# The autopilot's log mirror of its sim-time telemetry streams, a few messages each 100
# ms of sim time (autopilot/process/telemetry.py), packed from their fields here.
MIRRORED = (mavlink.MAVLink_heartbeat_message, mavlink.MAVLink_attitude_message,
            mavlink.MAVLink_local_position_ned_message,
            mavlink.MAVLink_global_position_int_message)
_MIRROR_LAYOUTS = {cls: FrameLayout(cls) for cls in MIRRORED}


def pack_message(msg: mavlink.MAVLink_message, mav: mavlink.MAVLink) -> bytes:
    """``msg.pack(mav)``: by its layout for the mirrored streams on an unsigned link, by
    pymavlink otherwise."""
    layout = _MIRROR_LAYOUTS.get(type(msg))
    if layout is None or mav.signing.sign_outgoing:
        return msg.pack(mav)
    return layout.pack_message(msg, mav)


@njit(cache=True)
def _crc_byte(byte: int, crc: int) -> int:
    """MAVLink's checksum (CRC-16/MCRF4XX, X.25) continued from ``crc`` by one byte."""
    tmp = (byte ^ (crc & 0xFF)) & 0xFF
    tmp = (tmp ^ (tmp << 4)) & 0xFF
    return ((crc >> 8) ^ (tmp << 8) ^ (tmp << 3) ^ (tmp >> 4)) & 0xFFFF


@njit(cache=True)
def crc_x25(buf: np.ndarray, start: int, end: int, crc: int) -> int:
    """MAVLink's checksum of buf[start:end], continued from ``crc``."""
    for i in range(start, end):
        crc = _crc_byte(buf[i], crc)
    return crc


@njit(cache=True)
def pack_frame(out: np.ndarray, at: int, ints: np.ndarray, floats: np.ndarray,
               codes: np.ndarray, offsets: np.ndarray, msgid: int, crc_extra: int, seq: int,
               sysid: int, compid: int) -> int:
    """The frame of the flat values written at out[at:]; returns where it ends."""
    payload = at + HEADER_BYTES
    scratch = np.empty(1, dtype=np.float64)
    f64 = scratch
    f32 = scratch.view(np.float32)
    raw = scratch.view(np.uint8)
    end = payload
    for i in range(codes.size):
        code = codes[i]
        p = payload + offsets[i]
        if code >= F32:
            if code == F32:
                f32[0] = np.float32(floats[i])
                n = 4
            else:
                f64[0] = floats[i]
                n = 8
            for k in range(n):
                out[p + k] = raw[k]
        else:
            v = ints[i]
            n = TYPE_BYTES[code]
            for k in range(n):
                out[p + k] = (v >> (8 * k)) & 0xFF
        end = p + n
    while end > payload + 1 and out[end - 1] == 0:  # trailing zeros trimmed, one kept
        end -= 1
    length = end - payload
    out[at] = MAGIC_V2
    out[at + 1] = length
    out[at + 2] = 0
    out[at + 3] = 0
    out[at + 4] = seq & 0xFF
    out[at + 5] = sysid & 0xFF
    out[at + 6] = compid & 0xFF
    out[at + 7] = msgid & 0xFF
    out[at + 8] = (msgid >> 8) & 0xFF
    out[at + 9] = (msgid >> 16) & 0xFF
    crc = _crc_byte(crc_extra, crc_x25(out, at + 1, end, 0xFFFF))
    out[end] = crc & 0xFF
    out[end + 1] = crc >> 8
    return end + CHECKSUM_BYTES


# Where a frame ends and its message id, from its header: contracts/mavlink.py's
# ``frame_size`` and ``frame_msgid`` (split_frames, datagram_frames), compiled from the
# same source.
frame_length = njit(cache=True)(frame_size)
msgid_at = njit(cache=True)(frame_msgid)


@njit(cache=True)
def checked_frame(buf: np.ndarray, at: int, crc_extra: int, payload_bytes: int) -> bool:
    """Whether the whole frame at buf[at] is a plain MAVLink 2 frame (no incompatibility
    flag) no longer than ``payload_bytes`` with a good checksum."""
    length = buf[at + 1]
    if buf[at] != MAGIC_V2 or buf[at + 2] != 0 or length > payload_bytes:
        return False
    end = at + HEADER_BYTES + length
    crc = _crc_byte(crc_extra, crc_x25(buf, at + 1, end, 0xFFFF))
    return crc == (buf[end] | buf[end + 1] << 8)


@njit(cache=True)
def unpack_payload(buf: np.ndarray, start: int, length: int, codes: np.ndarray,
                   offsets: np.ndarray, ints: np.ndarray, floats: np.ndarray) -> None:
    """The flat values of the payload at buf[start:start + length], the bytes beyond
    ``length`` read as zeros (MAVLink 2's trimmed payloads)."""
    scratch = np.zeros(1, dtype=np.float64)
    raw = scratch.view(np.uint8)
    f32 = scratch.view(np.float32)
    for i in range(codes.size):
        code = codes[i]
        p = offsets[i]
        n = TYPE_BYTES[code]
        if code >= F32:
            for k in range(n):
                raw[k] = buf[start + p + k] if p + k < length else 0
            floats[i] = np.float64(f32[0]) if code == F32 else scratch[0]
        else:
            v = 0
            for k in range(n):
                if p + k < length:
                    v |= np.int64(buf[start + p + k]) << (8 * k)
            if code in (I8, I16, I32) and v >= 1 << (8 * n - 1):  # sign-extended
                v -= 1 << (8 * n)
            ints[i] = v
