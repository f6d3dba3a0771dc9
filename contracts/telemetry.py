"""Zenoh telemetry: key expressions and record schemas, defined once (docs/architecture.md).

Keys (``V`` is the vehicle id, the autopilot's MAVLink system id):

=====================================  ========  =============================================
key                                    encoding  what
=====================================  ========  =============================================
``ivfm/vehicle/V/sitl/state``          CDR       truth state and plant perturbations, each sample
``ivfm/vehicle/V/autopilot/control``   CDR       controller internals, each control step
``ivfm/vehicle/V/autopilot/timing``    CDR       loop period, compute time, misses, each step
``ivfm/vehicle/V/{proc}/perturbation`` JSON      a perturbation took effect / ended
``ivfm/vehicle/V/{proc}/status``       JSON      1 Hz (wall) and final: counters per topic
``ivfm/vehicle/V/autopilot/scene``     JSON      what to draw: airframe, home, mission, fence,
                                                 rally (on change and 1 Hz sim time)
``ivfm/vehicle/V/{proc}/batch``        batch     the CDR records and mirror frames of a span
                                                 of sim time, in one put (below)
``mavlink/V/C/MSG``                    MAVLink   raw MAVLink 2 frames the autopilot produced
``ivfm/vehicle/V/{proc}/perturb``      query     perturbation requests (acknowledged)
``ivfm/vehicle/V/sitl/start``          query     release a held lockstep simulator
``ivfm/ground/logger/NAME/status``     query     what a logger has recorded
=====================================  ========  =============================================

Liveliness tokens: ``ivfm/vehicle/V/sitl``, ``ivfm/vehicle/V/autopilot``,
``ivfm/ground/logger/NAME``.

The CDR records are ROS 2 CDR (little endian) of the ``ros2msg`` schemas below, so the
MCAP log opens in Foxglove and PlotJuggler as is: the logger writes the payload it gets.
Every record starts with ``uint64 seq`` and ``int64 sim_time_us``; MAVLink mirror frames
carry the two in the Zenoh attachment (``<Qq``).

A process sends its CDR records and mirror frames in **batches**: one put on its
``batch`` key per span of sim time (``pack_batch``), each record keeping its own key,
payload and attachment; a subscriber takes them out with ``unbatched``. A put costs a
process tens of microseconds and wakes Zenoh's threads and every subscriber, so one put
per span instead of several per step is most of what telemetry costs the loop. The JSON
records (status, perturbation events, scene) go out on their own keys, after the batch
before them.
"""

from __future__ import annotations

import json
import struct
from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np

from contracts import AUTOPILOT, SITL
from contracts.mavlink import SIMULATOR_COMPID
from contracts.perturbation_effects import PLANT_EFFECTS
from contracts.vectors import CHANNEL_INTERNALS, CHANNELS, MEASUREMENT, REFERENCE

ROOT = "ivfm"
DEFAULT_PORT = 7447
DEFAULT_GROUND_ENDPOINT = f"tcp/127.0.0.1:{DEFAULT_PORT}"
MAX_VEHICLE_ID = 255

CDR_HEADER = b"\x00\x01\x00\x00"  # CDR, little endian
MIRROR_ATTACHMENT = struct.Struct("<Qq")  # seq, sim_time_us


def vehicle_key(vehicle: int, process: str, topic: str | None = None) -> str:
    check_vehicle_id(vehicle)
    base = f"{ROOT}/vehicle/{vehicle}/{process}"
    return base if topic is None else f"{base}/{topic}"


def logger_key(name: str, topic: str | None = None) -> str:
    base = f"{ROOT}/ground/logger/{name}"
    return base if topic is None else f"{base}/{topic}"


def mavlink_key(sysid: int, compid: int, message_name: str) -> str:
    return f"mavlink/{sysid}/{compid}/{message_name}"


def check_vehicle_id(vehicle: int) -> int:
    if isinstance(vehicle, bool) or not isinstance(vehicle, int) or \
            not 1 <= vehicle <= MAX_VEHICLE_ID:
        raise ValueError(f"vehicle id must be a whole number in [1, {MAX_VEHICLE_ID}], "
                         f"got {vehicle!r}")
    return vehicle


def parse_key(key: str) -> tuple[int, str, str] | None:
    """(vehicle, process, topic) of an ``ivfm/vehicle/...`` key, else None."""
    parts = key.split("/")
    if len(parts) != 5 or parts[0] != ROOT or parts[1] != "vehicle" or not parts[2].isdigit():
        return None
    return int(parts[2]), parts[3], parts[4]


# -- CDR record schemas ---------------------------------------------------------------------

_ROS_TYPES = {"u8": "uint64", "i8": "int64", "f8": "float64"}


@dataclass(frozen=True)
class RecordSchema:
    """A flat record: fixed fields (8-byte scalars and arrays), then float64 sequences."""

    name: str
    fields: tuple[tuple[str, str, int], ...]  # (name, u8 | i8 | f8, count; 0 = scalar)
    sequences: tuple[str, ...] = ()
    comment: str = ""

    @cached_property  # built once: a log's report decodes thousands of records
    def dtype(self) -> np.dtype:
        return np.dtype([(n, "<" + t, (c,)) if c else (n, "<" + t) for n, t, c in self.fields])

    @cached_property
    def fixed_size(self) -> int:
        return len(CDR_HEADER) + self.dtype.itemsize

    @property
    def ros2msg(self) -> str:
        lines = [f"# {self.comment}"] if self.comment else []
        for n, t, c in self.fields:
            lines.append(f"{_ROS_TYPES[t]}{f'[{c}]' if c else ''} {n}")
        lines.extend(f"float64[] {n}" for n in self.sequences)
        return "\n".join(lines) + "\n"

    def buffer(self) -> RecordBuffer:
        """A reusable record to fill by field name and encode."""
        return RecordBuffer(self)

    def decode(self, payload: bytes) -> dict[str, Any]:
        """Fields by name; raises ValueError on a payload that does not fit the schema."""
        sequences = self.sequence_arrays(payload)
        row = np.frombuffer(payload, dtype=self.dtype, count=1, offset=4)[0]
        out: dict[str, Any] = {n: row[n] for n, _t, _c in self.fields}
        out.update(zip(self.sequences, sequences, strict=True))
        return out

    def sequence_arrays(self, payload: bytes) -> list[np.ndarray]:
        """The float64 sequences after the fixed fields, in schema order, as views of the
        payload; raises ValueError on a payload that does not fit the schema."""
        at, size, out = self.fixed_size, len(payload), []
        if size < at or payload[:4] != CDR_HEADER:
            raise ValueError(f"{self.name}: payload of {size} bytes is not a "
                             f"{at}+ byte CDR record")
        for name in self.sequences:
            if at + 8 > size:
                raise ValueError(f"{self.name}: payload ends before sequence {name}")
            (count,) = struct.unpack_from("<I", payload, at)
            at += 8
            if at + 8 * count > size:
                raise ValueError(f"{self.name}: sequence {name} of {count} runs past the end")
            out.append(np.frombuffer(payload, dtype="<f8", count=count, offset=at))
            at += 8 * count
        if at != size:
            raise ValueError(f"{self.name}: {size - at} bytes left over")
        return out

    def offset(self, name: str, index: int = 0) -> int:
        """Where fixed field ``name`` (its ``index``-th value) starts in a payload: for a
        ``struct`` read of the few fields a reader needs, not the whole record."""
        return len(CDR_HEADER) + self.dtype.fields[name][1] + 8 * index

    def decode_many(self, payloads: list[bytes]) -> tuple[np.ndarray, list[list[np.ndarray]]]:
        """Many records at once (a log read back): their fixed fields as one structured
        array, a row per record, and each record's sequences; the same numbers as
        ``decode`` record by record, and the same ValueError for a payload that does not
        fit."""
        fixed = len(CDR_HEADER) + self.dtype.itemsize
        sequences = []
        for payload in payloads:
            self.check(payload)
            at, seqs = fixed, []
            for _name in self.sequences:
                (count,) = struct.unpack_from("<I", payload, at)
                seqs.append(np.frombuffer(payload, dtype="<f8", count=count, offset=at + 8))
                at += 8 + 8 * count
            sequences.append(seqs)
        rows = np.frombuffer(b"".join(p[len(CDR_HEADER):fixed] for p in payloads),
                             dtype=self.dtype)
        return rows, sequences

    def check(self, payload: bytes) -> None:
        """Cheap structural check (the logger's): header, sizes and sequence lengths."""
        size = len(payload)
        if size < self.fixed_size or payload[:4] != CDR_HEADER:
            raise ValueError(f"{self.name}: payload of {size} bytes is not a "
                             f"{self.fixed_size}+ byte CDR record")
        at = self.fixed_size
        for name in self.sequences:
            if at + 8 > size:
                raise ValueError(f"{self.name}: payload ends before sequence {name}")
            at += 8 + 8 * struct.unpack_from("<I", payload, at)[0]
        if at != size:
            raise ValueError(f"{self.name}: {size} bytes where the record says {at}")


class RecordBuffer:
    """One record of a schema, filled by field name (``record["seq"] = 3``) and encoded;
    kept between publications so a publisher allocates nothing per record."""

    def __init__(self, schema: RecordSchema) -> None:
        self.schema = schema
        self._row = np.zeros((), dtype=schema.dtype)
        self._fields = {name: self._row[name] for name, _t, _c in schema.fields}

    def __setitem__(self, name: str, value: Any) -> None:
        self._fields[name][...] = value

    def __getitem__(self, name: str) -> np.ndarray:
        return self._fields[name]

    def block(self, names: tuple[str, ...]) -> np.ndarray:
        """One writable (len(names), n) view over consecutive float fields of n values
        each, so a table fills them in one assignment."""
        dtype = self._row.dtype
        first, size = dtype.fields[names[0]][1], dtype.fields[names[0]][0].itemsize
        for i, name in enumerate(names):
            sub, offset = dtype.fields[name][:2]
            if offset != first + i * size or sub.itemsize != size or sub.base != np.float64:
                raise ValueError(f"{', '.join(names)} are not consecutive float fields of "
                                 "one size")
        return np.ndarray((len(names), size // 8), dtype="<f8", buffer=self._row,
                          offset=first)

    def run(self, names: tuple[str, ...]) -> np.ndarray:
        """One writable flat view over the consecutive fields ``names`` (in record order,
        of any sizes), all floats or all integers, so one assignment (or
        ``np.concatenate(..., out=)``) fills them all. Integers are viewed as int64: an
        unsigned field takes any count below 2**63 the same."""
        fields = self._row.dtype.fields
        kinds = {fields[name][0].base.kind for name in names}
        first = at = fields[names[0]][1]
        for name in names:
            sub, offset = fields[name][:2]
            if offset != at or kinds not in ({"f"}, {"i"}, {"i", "u"}, {"u"}):
                raise ValueError(f"{', '.join(names)} are not consecutive fields of one "
                                 "kind (float or integer)")
            at += sub.itemsize
        return np.ndarray(((at - first) // 8,), dtype="<f8" if kinds == {"f"} else "<i8",
                          buffer=self._row, offset=first)

    def encode(self, sequences: tuple[np.ndarray, ...] = ()) -> bytes:
        """The CDR payload: the fixed fields as filled, then ``sequences`` in schema order."""
        if len(sequences) != len(self.schema.sequences):
            raise ValueError(f"{self.schema.name} takes {len(self.schema.sequences)} "
                             f"sequences, got {len(sequences)}")
        out = [CDR_HEADER, self._row.tobytes()]
        for seq in sequences:
            out.append(struct.pack("<I4x", len(seq)))
            out.append(np.asarray(seq, dtype="<f8").tobytes())
        return b"".join(out)


# The controller's per-channel internals, each one array over the channels (CHANNELS).

CONTROL = RecordSchema(
    "ivfm_msgs/msg/Control",
    (("seq", "u8", 0), ("sim_time_us", "i8", 0), ("mode", "i8", 0), ("flags", "i8", 0),
     ("reference_time_s", "f8", 0), ("measurement", "f8", MEASUREMENT.size),
     ("reference", "f8", REFERENCE.size), ("kick_rad", "f8", 2), ("motor_commands", "f8", 4),
     *((f"ch_{name}", "f8", len(CHANNELS)) for name in CHANNEL_INTERNALS),
     ("theta_g", "f8", len(CHANNELS))),
    sequences=("theta_f_phi", "theta_f_theta", "theta_f_psi"),
    comment="IVFM autopilot, one control step. measurement: x y z vx vy vz phi theta psi "
            "and Euler rates (NED/FRD, SI). ch_*: per channel phi theta psi z x y. "
            "mode: index in FlightMode; flags: bit 0 armed, bit 2 failsafe",
)

TIMING = RecordSchema(
    "ivfm_msgs/msg/LoopTiming",
    (("seq", "u8", 0), ("sim_time_us", "i8", 0), ("deadline_misses", "i8", 0),
     ("compute_s", "f8", 0), ("period_s", "f8", 0)),
    comment="Autopilot loop timing on the wall clock (period NaN when the loop restarted)",
)

ESTIMATE = RecordSchema(
    "ivfm_msgs/msg/Estimate",
    (("seq", "u8", 0), ("sim_time_us", "i8", 0), ("flags", "i8", 0),
     ("position_ned_m", "f8", 3), ("velocity_ned_mps", "f8", 3), ("quaternion", "f8", 4),
     ("gyro_bias_rad_s", "f8", 3), ("accel_bias_mps2", "f8", 3), ("baro_offset_m", "f8", 0),
     ("tilt_sigma_rad", "f8", 0), ("yaw_sigma_rad", "f8", 0), ("horizontal_sigma_m", "f8", 0),
     ("vertical_sigma_m", "f8", 0), ("velocity_sigma_mps", "f8", 0),
     ("gps_test_ratio", "f8", 0), ("baro_test_ratio", "f8", 0), ("mag_test_ratio", "f8", 0)),
    comment="The autopilot's onboard estimate at one control step (flying on the estimator) "
            "and its health: flags bit 0 aligned, bit 1 converged, bit 2 GPS fused within 1 s; "
            "test ratios above 1 were rejected",
)
ESTIMATE_ALIGNED, ESTIMATE_CONVERGED, ESTIMATE_GPS_OK = 1, 2, 4

STATE = RecordSchema(
    "ivfm_msgs/msg/TruthState",
    (("seq", "u8", 0), ("sim_time_us", "i8", 0), ("position_ned_m", "f8", 3),
     ("velocity_ned_mps", "f8", 3), ("quaternion", "f8", 4), ("euler_rad", "f8", 3),
     ("euler_rate_rad_s", "f8", 3), ("body_rate_rad_s", "f8", 3), ("rotor_rad_s", "f8", 4),
     ("motor_commands", "f8", 4),
     *((name, "f8", effect.size) for name, effect in PLANT_EFFECTS.items())),
    comment="Simulator truth at one sample (before the step) and the plant perturbations "
            "in force",
)

CDR_TOPICS: dict[tuple[str, str], RecordSchema] = {
    (SITL, "state"): STATE, (AUTOPILOT, "control"): CONTROL, (AUTOPILOT, "timing"): TIMING,
    (AUTOPILOT, "estimate"): ESTIMATE,
}
JSON_TOPICS = ("status", "perturbation", "scene")
BATCH_TOPIC = "batch"

# Record modes by index (contracts.mavlink.FlightMode order) and flag bits.
FLAG_ARMED, FLAG_FAILSAFE = 1, 4


def schema_for_key(key: str) -> RecordSchema | str | None:
    """The CDR schema of a key, "json" for JSON records, "mavlink" for mirror frames,
    "batch" for a process's batches, None for keys outside the contract."""
    if key.startswith("mavlink/"):
        return "mavlink"
    parsed = parse_key(key)
    if parsed is None:
        return None
    _vehicle, process, topic = parsed
    if topic in JSON_TOPICS and process in (SITL, AUTOPILOT):
        return "json"
    if topic == BATCH_TOPIC and process in (SITL, AUTOPILOT):
        return "batch"
    return CDR_TOPICS.get((process, topic))


def json_record(seq: int, sim_time_us: int, **fields: Any) -> bytes:
    return json.dumps({"seq": seq, "sim_time_us": sim_time_us, **fields},
                      allow_nan=False, separators=(",", ":")).encode()


def decode_json_record(payload: bytes) -> dict[str, Any]:
    try:
        data = json.loads(payload)
    except (ValueError, UnicodeDecodeError) as exc:
        raise ValueError(f"JSON record does not parse: {exc}") from None
    if not isinstance(data, dict) or not isinstance(data.get("seq"), int) or \
            not isinstance(data.get("sim_time_us"), int):
        raise ValueError("JSON record lacks integer seq and sim_time_us")
    return data


JSON_RECORD_SCHEMA = json.dumps({
    "type": "object", "required": ["seq", "sim_time_us"],
    "properties": {"seq": {"type": "integer"}, "sim_time_us": {"type": "integer"}},
}).encode()


# -- batches ----------------------------------------------------------------------------
# A batch: b"IVB1", u16 key count, each key (u16 length, UTF-8), u32 record count, then
# three packed arrays over the records (u16 key index, u32 payload length, u8 attachment
# length, 0 for none), then the payloads end to end, then the attachments end to end.
BATCH_MAGIC = b"IVB1"
MAX_BATCH_KEYS = 1024
MAX_BATCH_RECORDS = 65_535
_U16, _U32 = struct.Struct("<H"), struct.Struct("<I")
Entry = tuple[str, bytes, bytes | None]  # key, payload, attachment


def pack_batch(keys: list[str], key_index: list[int], payloads: list[bytes],
               attachments: list[bytes]) -> bytes:
    """One batch of records: record i is on ``keys[key_index[i]]`` with ``payloads[i]``
    and ``attachments[i]`` (b"" for none)."""
    n = len(payloads)
    if not 0 < n <= MAX_BATCH_RECORDS or len(keys) > MAX_BATCH_KEYS:
        raise ValueError(f"a batch holds 1-{MAX_BATCH_RECORDS} records on at most "
                         f"{MAX_BATCH_KEYS} keys, got {n} on {len(keys)}")
    parts = [BATCH_MAGIC, _U16.pack(len(keys))]
    for key in keys:
        raw = key.encode()
        parts += (_U16.pack(len(raw)), raw)
    parts += (struct.pack(f"<I{n}H{n}I", n, *key_index, *map(len, payloads)),
              bytes(map(len, attachments)), *payloads, *attachments)
    return b"".join(parts)


def unpack_batch(batch_key: str, payload: bytes) -> list[Entry]:
    """The records of a batch put on ``batch_key``; ValueError if it does not parse, or
    holds a key beyond what its sender publishes (its own ``ivfm/vehicle/V/PROC/...``
    keys; the autopilot's MAVLink mirror, ``mavlink/V/...``, and the simulator's,
    ``mavlink/V/51/...``)."""
    parsed = parse_key(batch_key)
    if parsed is None or parsed[2] != BATCH_TOPIC:
        raise ValueError(f"{batch_key} is not a batch key")
    vehicle, process, _ = parsed
    own = f"{ROOT}/vehicle/{vehicle}/{process}/"
    mirror = (f"mavlink/{vehicle}/" if process == AUTOPILOT else
              f"mavlink/{vehicle}/{SIMULATOR_COMPID}/" if process == SITL else None)
    size = len(payload)
    try:
        if payload[:4] != BATCH_MAGIC:
            raise ValueError("it does not start with IVB1")
        (nkeys,), at = _U16.unpack_from(payload, 4), 6
        if nkeys > MAX_BATCH_KEYS:
            raise ValueError(f"{nkeys} keys is over {MAX_BATCH_KEYS}")
        keys = []
        for _ in range(nkeys):
            (length,) = _U16.unpack_from(payload, at)
            key = payload[at + 2:at + 2 + length].decode()
            if len(key) != length or not (key.startswith(own) or
                                          (mirror and key.startswith(mirror))):
                raise ValueError(f"key {key!r} is not one its sender publishes")
            if key.endswith("/" + BATCH_TOPIC):
                raise ValueError("a batch inside a batch")
            keys.append(key)
            at += 2 + length
        (n,), at = _U32.unpack_from(payload, at), at + 4
        if not 0 < n <= MAX_BATCH_RECORDS or at + 7 * n > size:
            raise ValueError(f"{n} records do not fit its {size} bytes")
        index = struct.unpack_from(f"<{n}H", payload, at)
        lengths = struct.unpack_from(f"<{n}I", payload, at + 2 * n)
        attached = payload[at + 6 * n:at + 7 * n]
        at += 7 * n
        if max(index) >= nkeys:
            raise ValueError(f"a record names key {max(index)} of {nkeys}")
        if at + sum(lengths) + sum(attached) != size:
            raise ValueError(f"its records take {at + sum(lengths) + sum(attached)} of its "
                             f"{size} bytes")
    except (struct.error, UnicodeDecodeError) as exc:
        raise ValueError(f"batch on {batch_key} does not parse: {exc}") from None
    except ValueError as exc:
        raise ValueError(f"batch on {batch_key} refused: {exc}") from None
    out = []
    extra = at + sum(lengths)  # the attachments follow the payloads
    for k, length, attached_length in zip(index, lengths, attached, strict=True):
        record = payload[at:at + length]
        at += length
        if attached_length:
            out.append((keys[k], record, payload[extra:extra + attached_length]))
            extra += attached_length
        else:
            out.append((keys[k], record, None))
    return out


def unbatched(key: str, payload: bytes, attachment: bytes | None) -> list[Entry]:
    """The records a put carries: a batch's, or the one record (ValueError: a bad batch)."""
    if key.endswith("/" + BATCH_TOPIC) and schema_for_key(key) == "batch":
        return unpack_batch(key, payload)
    return [(key, payload, attachment)]
