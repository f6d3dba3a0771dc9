"""What a run leaves on disk, written and read in one place: the run folder's files, the
MCAP log read back (no Zenoh needed), and the run record every report is computed from.
"""

from __future__ import annotations

import json
import math
import struct
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, BinaryIO

import numpy as np
from mcap.data_stream import ReadDataStream
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.records import Chunk, Message
from mcap.stream_reader import get_chunk_data_stream

from contracts.atomic_file import write_atomic
from contracts.telemetry import AUTOPILOT, CONTROL, SITL, STATE, vehicle_key
from contracts.vectors import CHANNEL_INTERNALS, MEASUREMENT

if TYPE_CHECKING:  # the logger reads logs without the scenario (and vehicle) modules
    from ground.scenario.scenario_file import Scenario

RUN_FILE = "run.json"  # how ``ivfm run`` flew the run
SCENARIO_FILE = "scenario.toml"  # the scenario it flew
METRICS_FILE = "metrics.json"
ULOG_FILE = "flight.ulg"  # the run as a PX4 flight log (ivfm run --ulog, ivfm ground ulog)
MAX_POSITION_M = 1e3  # a run that goes this far from home, or to NaN, has diverged


@dataclass
class RunRecord:
    """Time series of one run, one row per control period (values before the step)."""

    scenario: str
    controller: str
    plant: str
    period_s: float
    time_s: np.ndarray  # (N,)
    measurement: np.ndarray  # (N, 12) position, velocity, Euler, Euler rates
    reference: np.ndarray  # (N, 18)
    kick: np.ndarray  # (N, 2)
    motor_commands: np.ndarray  # (N, 4) in [0, 1]
    channel_telemetry: np.ndarray  # (N, 6, 10) per channel internals (NaN where unused)
    theta_g: np.ndarray  # (N, 6)
    theta_f: list[np.ndarray]  # per attitude channel (N, len)
    wall_time_s: float
    diverged: bool
    # The true state at each step when the controller flew on an estimate (else None:
    # the measurement is the truth).
    truth: np.ndarray | None = None
    # Read from a log only (None in process): each step's sim time, mode index
    # (FlightMode order) and flags (contracts.telemetry FLAG_*), for the run's events.
    sim_time_us: np.ndarray | None = None
    mode_index: np.ndarray | None = None
    flags: np.ndarray | None = None
    # In process: the first step's wall time, which loads (or compiles) the numerical core
    # and is not part of wall_time_s.
    startup_wall_s: float = 0.0

    @property
    def true_state(self) -> np.ndarray:
        return self.measurement if self.truth is None else self.truth


def left_the_envelope(measurement: np.ndarray) -> bool:
    """The divergence test of every run (one measurement or rows of them)."""
    return bool(not np.all(np.isfinite(measurement)) or
                np.max(np.abs(measurement[..., MEASUREMENT.position_ned_m])) > MAX_POSITION_M)


def write_json(path: Path, data: Any) -> None:
    """Write JSON atomically (temp file + rename) so no half-written file is left."""
    path.parent.mkdir(parents=True, exist_ok=True)
    write_atomic(path, json.dumps(data, indent=2, allow_nan=False) + "\n")



def log_files(path: Path) -> list[Path]:
    """The finished MCAP files of a run folder (in order), or the one file given."""
    path = Path(path)
    if path.is_dir():
        files = sorted(path.glob("*.mcap"))
        if not files:
            raise ValueError(f"no .mcap file in {path}")
        return files
    if not path.exists():
        raise ValueError(f"no such log: {path}")
    return [path]


class LogRecords:
    """The messages of a log on some topics, read in one pass: a report takes several
    sets of records (the control records, perturbation events, texts), and each pass over
    the file costs the same whatever it keeps. ``iter_messages`` takes it as a log."""

    def __init__(self, path: Path, topic_prefixes: tuple[str, ...]) -> None:
        self.path = Path(path)
        self.messages = []
        for file in log_files(path):
            indexed = _indexed_messages(file, topic_prefixes)
            self.messages += indexed if indexed is not None else [
                m for m in iter_messages(file) if m[0].startswith(topic_prefixes)]

    def __str__(self) -> str:
        return str(self.path)


def iter_messages(path: Path | LogRecords, topic_prefix: str = ""
                  ) -> Iterator[tuple[str, Any, bytes]]:
    """(topic, MCAP message, data) over the log files of ``path`` (or of the records read
    once)."""
    if isinstance(path, LogRecords):
        yield from (m for m in path.messages if m[0].startswith(topic_prefix))
        return
    for file in log_files(path):
        with open(file, "rb") as f:
            try:
                reader = make_reader(f)
                for _schema, channel, message in reader.iter_messages(log_time_order=False):
                    if channel.topic.startswith(topic_prefix):
                        yield channel.topic, message, message.data
            except McapError as exc:
                raise ValueError(f"{file} is not a readable MCAP file: {exc}") from None
            except Exception as exc:  # noqa: BLE001 (only the reader's: see below)
                # A damaged file fails inside the reader in many ways (a chunk that does
                # not decompress, a record cut short); the caller's own errors are not
                # raised in here (they happen where it takes the yielded message).
                raise ValueError(f"{file} is damaged: {type(exc).__name__}: {exc}") from None


_MESSAGE = struct.Struct("<BQHIQQ")  # a Message record's opcode, length and fixed fields
_INDEX = struct.Struct("<BQHI")  # a Message Index record's opcode, length, channel, size
_OP_MESSAGE, _OP_MESSAGE_INDEX = 0x05, 0x07


def _indexed_messages(file: Path, topic_prefixes: tuple[str, ...]
                      ) -> list[tuple[str, Message, bytes]] | None:
    """The messages of ``file`` on the topics, in file order, found through its index:
    only the chunks that hold them are decompressed, and only their records parsed (the
    reader's own pass parses every record in Python: most of a report's time). None
    when the index cannot be used (a salvaged or damaged file): read it whole instead.
    The MCAP library reads the summary and the chunks; this reads the message indexes
    and the messages they point to (MCAP's record layout)."""
    try:
        with open(file, "rb") as f:
            summary = make_reader(f).get_summary()
            if summary is None or not summary.chunk_indexes:
                return None
            topics = {cid: channel.topic for cid, channel in summary.channels.items()
                      if channel.topic.startswith(topic_prefixes)}
            found: list[tuple[str, Message, bytes]] = []
            for index in summary.chunk_indexes:
                wanted = [cid for cid in index.message_index_offsets if cid in topics]
                if not wanted:
                    continue
                f.seek(index.chunk_start_offset + 1 + 8)
                stream, size = get_chunk_data_stream(Chunk.read(ReadDataStream(f)))
                chunk = stream.read(size)
                offsets = [(offset, cid) for cid in wanted
                           for offset in _message_offsets(f, index.message_index_offsets[cid],
                                                          cid)]
                for offset, cid in sorted(offsets):
                    op, length, channel_id, sequence, log_time, publish_time = \
                        _MESSAGE.unpack_from(chunk, offset)
                    end = offset + 9 + length
                    if op != _OP_MESSAGE or channel_id != cid or length < 22 or \
                            end > len(chunk):
                        return None
                    payload = chunk[offset + _MESSAGE.size:end]
                    found.append((topics[cid], Message(cid, log_time, payload, publish_time,
                                                       sequence), payload))
            return found
    except Exception:  # noqa: BLE001 (a damaged file fails in the reader, the
        # decompressor or here in many ways; read whole, it is refused with its reason)
        return None


def _message_offsets(f: BinaryIO, at: int, channel_id: int) -> list[int]:
    """The offsets in its chunk of one channel's messages, from its Message Index record
    at ``at`` in the file; ValueError if the record is not that."""
    f.seek(at)
    op, length, cid, size = _INDEX.unpack(f.read(_INDEX.size))
    if op != _OP_MESSAGE_INDEX or cid != channel_id or size % 16 or size + 6 != length:
        raise ValueError("not the message index the chunk index points to")
    pairs = np.frombuffer(f.read(size), dtype="<u8")
    if pairs.size * 8 != size:
        raise ValueError("a message index cut short")
    return pairs[1::2].tolist()


def control_records(log: Path | LogRecords, vehicle: int) -> dict[str, np.ndarray]:
    """The autopilot's control records of one vehicle as arrays (one row per step), plus
    ``log_time_ns``; checks that no sequence number is missing."""
    key = vehicle_key(vehicle, AUTOPILOT, "control")
    payloads, log_times = [], []
    for topic, message, data in iter_messages(log, key):
        if topic != key:
            continue
        payloads.append(data)
        log_times.append(message.log_time)
    if not payloads:
        raise ValueError(f"no control records of vehicle {vehicle} ({key}) in {log}")
    rows, sequences = CONTROL.decode_many(payloads)
    order = np.argsort(rows["seq"], kind="stable")  # by sequence number, as sent
    out: dict[str, Any] = {name: rows[name][order] for name, _kind, _count in CONTROL.fields}
    for i, name in enumerate(CONTROL.sequences):  # theta_f_phi, theta_f_theta, theta_f_psi
        out[name] = np.array([sequences[j][i] for j in order])
    out["log_time_ns"] = np.array(sorted(log_times))
    out["missing_count"] = missing_count(out["seq"])
    return out


def missing_count(seq: np.ndarray) -> int:
    """How many sequence numbers between the first and the last of ``seq`` (sorted) are
    absent: counted, not listed, since a damaged record's number may be 2**63 (listing
    that range wanted 48 TiB in the long fuzz run)."""
    return int(seq[-1]) - int(seq[0]) + 1 - len(set(seq.tolist()))


def truth_at(log: Path | LogRecords, vehicle: int, sim_time_us: np.ndarray) -> np.ndarray:
    """The simulator's true state (the measurement layout) at each of the given sample
    times, from its STATE records."""
    key = vehicle_key(vehicle, SITL, "state")
    by_time: dict[int, np.ndarray] = {}
    for topic, _message, data in iter_messages(log, key):
        if topic != key:
            continue
        r = STATE.decode(data)
        row = np.empty(MEASUREMENT.size)
        row[MEASUREMENT.position_ned_m] = r["position_ned_m"]
        row[MEASUREMENT.velocity_ned_mps] = r["velocity_ned_mps"]
        row[MEASUREMENT.euler_rad] = r["euler_rad"]
        row[MEASUREMENT.euler_rate_rad_s] = r["euler_rate_rad_s"]
        by_time[int(r["sim_time_us"])] = row
    missing = [int(t) for t in sim_time_us if int(t) not in by_time]
    if missing:
        raise ValueError(f"the log lacks the simulator's truth at {len(missing)} control "
                         f"steps (first t = {missing[0] / 1e6:.3f} s) of vehicle {vehicle}")
    return np.array([by_time[int(t)] for t in sim_time_us])


def record_from_log(log: Path | LogRecords, vehicle: int, scenario: Scenario,
                    controller: str, plant: str, rate_hz: float,
                    with_truth: bool = False) -> RunRecord:
    """The run as arrays; ``with_truth``: the controller flew on an estimate, so the truth
    comes from the simulator's records."""
    r = control_records(log, vehicle)
    n = len(r["seq"])
    measurement = r["measurement"]
    internals = np.stack([r[f"ch_{name}"] for name in CHANNEL_INTERNALS], axis=2)
    wall = (r["log_time_ns"][-1] - r["log_time_ns"][0]) / 1e9 if n > 1 else math.nan
    diverged = bool(n < round(scenario.duration_s * rate_hz) or r["missing_count"] or
                    left_the_envelope(measurement))
    return RunRecord(
        scenario=scenario.name, controller=controller, plant=plant, period_s=1.0 / rate_hz,
        time_s=r["reference_time_s"], measurement=measurement, reference=r["reference"],
        kick=r["kick_rad"], motor_commands=r["motor_commands"], channel_telemetry=internals,
        theta_g=r["theta_g"], theta_f=[r["theta_f_phi"], r["theta_f_theta"], r["theta_f_psi"]],
        wall_time_s=wall or math.nan, diverged=diverged,
        truth=truth_at(log, vehicle, r["sim_time_us"]) if with_truth else None,
        sim_time_us=r["sim_time_us"], mode_index=r["mode"], flags=r["flags"])


def perturbation_events(log: Path | LogRecords, vehicle: int) -> list[dict[str, Any]]:
    """Every perturbation the vehicle's processes applied, with the sim time it took effect."""
    events = []
    for process in (SITL, AUTOPILOT):
        key = vehicle_key(vehicle, process, "perturbation")
        for topic, _message, data in iter_messages(log, key):
            if topic == key:
                events.append({"process": process, **json.loads(data)})
    return sorted(events, key=lambda e: (e["sim_time_us"], e["process"], e["seq"]))


