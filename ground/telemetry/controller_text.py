"""The controller's plot-ready record on the Foxglove view's ``/vehicleV/controller``
channel (ground/telemetry/foxglove_view.py): per channel its internals by name, the
motors, mode and flags, written as JSON 50 times a sim second from a template."""

from __future__ import annotations

import json
import math
import operator
import struct
from typing import Any

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
    text, as ``json.dumps`` writes them; NaN and infinities are null (a gap in a plot)."""

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
        self._template = skeleton.replace("%", "%%").replace(json.dumps(hole), "%s")
        self.schema = json_schema(typed)
        self._modes = [json.dumps(m.name) for m in _MODES]

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
        texts = list(map(float.__repr__, numbers))
        if not math.isfinite(sum(numbers)):  # some NaN or infinity (or a sum that overflows)
            texts = [_NOT_FINITE.get(t, t) for t in texts]
        mode = self._modes[mode_index] if 0 <= mode_index < len(self._modes) else '""'
        armed = "true" if flags & FLAG_ARMED else "false"
        failsafe = "true" if flags & FLAG_FAILSAFE else "false"
        text = self._template % (texts[0], mode, armed, failsafe, *texts[1:])
        return JsonText(text.encode(), self.schema)


_NOT_FINITE = {"nan": "null", "inf": "null", "-inf": "null"}  # json's null for these
CONTROLLER_TEXT = ControllerText()
