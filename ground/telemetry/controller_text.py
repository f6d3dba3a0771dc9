"""The controller's plot-ready record on the Foxglove view's ``/vehicleV/controller``
channel (ground/telemetry/foxglove_view.py): per channel its internals by name, the
motors, mode and flags, written as JSON 50 times a sim second from a template."""

from __future__ import annotations

import json
import operator
import struct
from typing import Any

import orjson

from contracts.modes import FlightMode
from contracts.telemetry import CONTROL, FLAG_ARMED, FLAG_FAILSAFE
from contracts.vectors import CHANNEL_INTERNALS, CHANNELS
from ground.telemetry.foxglove_scene import JsonText, json_schema

# Names for the channel internals in plot-ready records.
INTERNAL_NAMES = {"ref": "reference", "y": "measured", "e": "error",
                  "e_s": "sliding_surface", "e_eps": "boundary_layer_distance",
                  "f_hat": "f_hat", "u_eq": "u_eq", "u_s": "u_s", "v": "control",
                  "theta_g_channel": "theta_g"}
INTERNAL_FIELDS = tuple(INTERNAL_NAMES[name] for name in CHANNEL_INTERNALS)
_MODES = tuple(FlightMode)


class ControllerText:
    """The controller's plot-ready record (per channel its internals by name, the motors,
    mode and flags) as JSON, filled into a template: the exact bytes ``encode`` gives the
    same record built as a dict, at a fraction of the cost (tests/ground/
    test_foxglove_view.py builds the dict and compares). Numbers are Python's float
    text, as ``json.dumps`` writes them; NaN and infinities are null (a gap in a plot).

    The numbers' text comes from orjson: the same shortest digits as Python's ``repr``
    for 1.6 us where ``repr`` took 45 us for the record's 70 (the largest part of the
    logger's drawing). The two write every finite number alike except below 1e-4 in
    magnitude, where Python writes ``1e-05`` and orjson ``0.00001`` or ``1e-5``
    (checked over millions of values); those few are written again by ``repr``."""

    def __init__(self) -> None:
        offsets = {name: CONTROL.dtype.fields[name][1] for name, _t, _c in CONTROL.fields}
        first = offsets["reference_time_s"]  # float64 fields from here to the fixed end
        self._floats = struct.Struct(f"<{(CONTROL.dtype.itemsize - first) // 8}d")
        self._at = 4 + first  # after the CDR header

        def at(name: str, count: int) -> list[int]:
            start = (offsets[name] - first) // 8
            return list(range(start, start + count))

        channels = len(CHANNELS)
        # The record's numbers in the template's order: the motors, each channel's
        # internals, theta_g (between them go t_s, the speed and the theta_f norms).
        self._pick = operator.itemgetter(
            *at("motor_commands", 4),
            *(at(f"ch_{name}", channels)[i] for i in range(channels)
              for name in CHANNEL_INTERNALS),
            *at("theta_g", channels))
        hole, typed = "\x01", self._record(lambda kind: kind)  # a slot, and its JSON type
        skeleton = json.dumps(self._record(lambda _kind: hole), separators=(",", ":"))
        self._template = skeleton.replace("%", "%%").replace(json.dumps(hole), "%s").encode()
        self.schema = json_schema(typed)
        self._modes = [json.dumps(m.name).encode() for m in _MODES]

    @staticmethod
    def _record(value: Any) -> dict[str, Any]:
        """The record's layout, each slot ``value(an example of its type)``."""
        number = 0.0
        record: dict[str, Any] = {"t_s": value(number), "mode": value(""),
                                  "armed": value(False), "failsafe": value(False),
                                  "motors": [value(number) for _ in range(4)],
                                  "speed_mps": value(number)}
        for i, channel in enumerate(CHANNELS):
            record[channel] = {name: value(number) for name in INTERNAL_FIELDS}
            if i < 3:
                record[channel]["theta_f_norm"] = value(number)
        record["theta_g"] = {channel: value(number) for channel in CHANNELS}
        return record

    def encode(self, payload: bytes, t_us: int, mode_index: int, flags: int,
               speed_mps: float, theta_f_norms: list[float]) -> JsonText:
        r = self._pick(self._floats.unpack_from(payload, self._at))
        n = len(CHANNEL_INTERNALS)
        numbers = (t_us / 1e6, *r[:4], speed_mps, *r[4:4 + n], theta_f_norms[0],
                   *r[4 + n:4 + 2 * n], theta_f_norms[1], *r[4 + 2 * n:4 + 3 * n],
                   theta_f_norms[2], *r[4 + 3 * n:])
        text = orjson.dumps(numbers)  # b"[n,n,...]", NaN and infinities null
        texts = text[1:-1].split(b",")
        for marker in _BELOW_1E_4:  # the numbers below 1e-4, written again as Python does
            at = text.find(marker)
            while at >= 0:
                i = text.count(b",", 0, at)
                texts[i] = repr(float(texts[i])).encode()
                at = text.find(marker, at + 1)
        mode = self._modes[mode_index] if 0 <= mode_index < len(self._modes) else b'""'
        armed = b"true" if flags & FLAG_ARMED else b"false"
        failsafe = b"true" if flags & FLAG_FAILSAFE else b"false"
        return JsonText(self._template % (texts[0], mode, armed, failsafe, *texts[1:]),
                        self.schema)


# What orjson writes for any number below 1e-4 in magnitude (and only for a few others,
# such as 10.00001, which repr writes the same): an exponent, or four zeros after the point.
_BELOW_1E_4 = (b"e-", b"0.0000")


CONTROLLER_TEXT = ControllerText()
