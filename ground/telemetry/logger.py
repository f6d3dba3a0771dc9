"""The ground logger: every telemetry record it hears, into MCAP (docs/architecture.md).

* One MCAP channel per Zenoh key; the CDR records are written as they arrive with their
  ``ros2msg`` schema (Foxglove and PlotJuggler decode them), JSON records with a JSON
  schema, MAVLink mirror frames with message encoding ``mavlink``. ``log_time`` is the
  wall time of arrival, ``publish_time`` the record's sim time, ``sequence`` its seq.
* Small chunks: a chunk closes when it reaches ``chunk_bytes`` or ``flush_period_s`` has
  passed, so a crash loses at most the last fraction of a second.
* The file being written is ``NAME.mcap.active``; it becomes ``NAME.mcap`` when finished.
  At start the logger salvages any ``.active`` file left by a crash: every complete record
  is copied into a finished file.
* Past ``rotate_bytes``, or ``rotate_chunks`` chunks, the file is finished and the next
  one started: the writer keeps each chunk's index in memory until its file is finished,
  so the chunk cap is what keeps the logger's memory flat over a long run.
* Records wait for the loop in an inbox bounded in puts and in bytes (past either, dropped
  and counted); once a backlog is written, the memory it took goes back to the system
  (``ground/telemetry/inbox.py``): otherwise a logger starved of CPU for a while kept
  its backlog's peak as resident memory for good.
* A record that does not fit its key's schema is refused (counted, reported on stderr and
  in the status reply), not written.
* Beside the records, what Foxglove draws (``ground/telemetry/foxglove_view.py``: transforms, the
  scene, the path, plot-ready controller and estimator channels, the vehicle's texts as
  logs), decimated on sim time; the same messages go to a live view when one is attached.
"""

from __future__ import annotations

import contextlib
import json
import queue
import re
import signal
import struct
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import zenoh

from contracts import timeline
from contracts.realtime import ProcessUsage
from contracts.stop_request import StopRequest
from contracts.telemetry import (
    MIRROR_ATTACHMENT,
    RecordSchema,
    decode_json_record,
    logger_key,
    parse_key,
    schema_for_key,
    unpack_batch,
)
from contracts.zenoh_link import ZenohOptions, open_session
from ground.telemetry.drawing import Drawing
from ground.telemetry.foxglove_view import Output, warm_up
from ground.telemetry.inbox import Inbox
from ground.telemetry.log_files import PROCESS, Counters, LogFiles

SUBSCRIBED = ("ivfm/vehicle/**", "mavlink/**")
# Bounds under hostile traffic (docs/telemetry.md, "Limits"): distinct keys with their
# own channel and counters, the longest key, and records waiting for the writer.
MAX_KEYS = 1024
MAX_KEY_CHARS = 256
MAX_INBOX = 200_000  # puts (a batch is one)
MAX_INBOX_BYTES = 128 * 1024 * 1024  # their payloads: ~4 min of one vehicle at 250 Hz
MAX_QUERIES = 64  # status queries waiting for the loop
SILENCE_S = 1.0  # records had been coming (250 Hz and more) and none for this long: say so
_NAME = re.compile(r"^[A-Za-z0-9_.-]{1,64}$")
_NEW_KEY = object()  # a key not heard before


@dataclass
class LoggerConfig:
    out_dir: Path
    zenoh: ZenohOptions
    name: str = "logger"
    prefix: str = "telemetry"
    chunk_bytes: int = 256 * 1024
    flush_period_s: float = 0.25
    rotate_bytes: int = 512 * 1024 * 1024
    rotate_chunks: int = 512  # ~0.7 MB of chunk index; at 4 chunks/s, a file per 2 min
    compression: str = "zstd"
    foxglove: bool = True  # write what Foxglove draws beside the records
    view_rate_hz: float = 50.0  # ... decimated to this rate of sim time

    def __post_init__(self) -> None:
        for label, value in (("name", self.name), ("prefix", self.prefix)):
            if not _NAME.match(value):
                raise ValueError(f"logger {label} must be 1-64 letters, digits, '.', '_' or "
                                 f"'-', got {value!r}")
        if not 1024 <= self.chunk_bytes <= 64 * 1024 * 1024:
            raise ValueError(f"chunk size must be in [1 KiB, 64 MiB], got {self.chunk_bytes}")
        if not 0.01 <= self.flush_period_s <= 1.0:
            raise ValueError(f"flush period must be in [0.01, 1] s, got {self.flush_period_s}")
        if self.rotate_bytes < 1024 * 1024:
            raise ValueError(f"rotation size must be at least 1 MiB, got {self.rotate_bytes}")
        if self.rotate_chunks < 16:
            raise ValueError(f"rotation chunk count must be at least 16, got "
                             f"{self.rotate_chunks}")
        if self.compression not in ("zstd", "lz4", "none"):
            raise ValueError(f"compression must be zstd, lz4 or none, got {self.compression!r}")


class SilenceWatch:
    """Says when records stop coming (a vehicle, or the Zenoh link or router between it
    and the logger, is down) and when they come again: once each, on an injected clock."""

    def __init__(self, log: Callable[[str], None], silence_s: float = SILENCE_S) -> None:
        self.log = log
        self.silence_s = silence_s
        self.last_s: float | None = None  # the last record's arrival (none yet: quiet)
        self.silent = False

    def update(self, now_s: float, records: int) -> None:
        if records:
            if self.silent:
                self.log(f"records again after {now_s - self.last_s:.1f} s of silence")
                self.silent = False
            self.last_s = now_s
        elif (not self.silent and self.last_s is not None
              and now_s - self.last_s >= self.silence_s):
            self.silent = True
            self.log(f"no records for {self.silence_s:g} s: the vehicles, or the Zenoh link "
                     "(or router) between them and this logger, are down")


class Logger:
    """Zenoh in, files out: the subscriptions fill an inbox that the loop drains into
    the files (``LogFiles``), with what Foxglove draws of each record beside it (and to
    a live view: ``Drawing``), and answers status queries between drains."""

    def __init__(self, config: LoggerConfig, log: Callable[[str], None] | None = None,
                 live: Callable[[Output], None] | None = None) -> None:
        self.config = config
        self.log = log or (lambda text: print(f"logger: {text}", file=sys.stderr, flush=True))
        self.counters = Counters()
        # (key, payload, attachment, log_time_ns) from Zenoh's threads to the loop
        self._inbox = Inbox(MAX_INBOX, MAX_INBOX_BYTES)
        self._queries: queue.SimpleQueue[zenoh.Query] = queue.SimpleQueue()
        self._stop = StopRequest()
        self.files = LogFiles(config.out_dir, config.prefix, config.chunk_bytes,
                              config.compression, config.rotate_bytes, config.rotate_chunks,
                              self.counters, self.log)
        # What Foxglove draws, beside the records and to a live view's publish, or None.
        self.drawing = (Drawing(config.view_rate_hz, config.foxglove, live, self.files,
                                self.counters, self.log)
                        if config.foxglove or live is not None else None)
        self._warned: dict[str, float] = {}
        # Each key heard (at most MAX_KEYS: past it a new key is refused) and its schema.
        self._schemas: dict[str, RecordSchema | str | None] = {}
        self._drawn: set[str] = set()  # of those, the keys whose records Foxglove draws
        self.usage = ProcessUsage()

    def stop(self, *_args: Any) -> None:
        timeline.mark(PROCESS, "stop asked")
        self._stop.set()

    # -- records -------------------------------------------------------------------------
    def _on_sample(self, sample: zenoh.Sample) -> None:
        attachment = sample.attachment
        size_bytes = len(sample.payload) + (len(attachment) if attachment is not None else 0)
        if not self._inbox.put((str(sample.key_expr), sample.payload.to_bytes(),
                                attachment.to_bytes() if attachment is not None else None,
                                time.time_ns()), size_bytes):
            self.counters.inbox_dropped += 1

    def _write(self, key: str, payload: bytes, attachment: bytes | None,
               log_time_ns: int) -> None:
        schema = self._schemas.get(key, _NEW_KEY)
        if schema is _NEW_KEY:
            c = self.counters
            if len(self._schemas) >= MAX_KEYS or len(key) > MAX_KEY_CHARS:
                c.rejected += 1
                c.keys_over_limit += 1
                c.last_error = (f"a record on a new key past the {MAX_KEYS}-key limit, or a "
                                f"key over {MAX_KEY_CHARS} characters ({c.keys_over_limit} "
                                "so far)")
                return
            schema = self._schemas[key] = schema_for_key(key)
            if self.drawing is not None and self.drawing.draws(key):
                self._drawn.add(key)
        if schema == "batch":  # a span of a process's records: each written as it came
            try:
                entries = unpack_batch(key, payload)
            except ValueError as exc:
                self._refuse(key, str(exc))
                return
            write = self._write
            for entry_key, entry_payload, entry_attachment in entries:
                write(entry_key, entry_payload, entry_attachment, log_time_ns)
            return
        try:
            seq, sim_time_us = self._check(key, schema, payload, attachment)
        except ValueError as exc:
            self._refuse(key, str(exc))
            return
        c = self.counters
        if c.write_error:
            c.unwritten += 1
            return
        f = self.files.file
        try:
            f.add(f.channel(key, schema), log_time_ns, sim_time_us * 1000, seq, payload)
        except OSError as exc:  # a chunk filled and the disk refused it
            self.files.write_failed(exc)
            c.unwritten += 1
            return
        c.records += 1
        if c.records == 1:  # the flight's cost from its first record, not the start-up's
            self.usage.restart()
        c.per_key[key] += 1
        if key in self._drawn:
            self.drawing.draw(key, payload, attachment, log_time_ns)

    def _check(self, key: str, schema: RecordSchema | str | None, payload: bytes,
               attachment: bytes | None) -> tuple[int, int]:
        """(seq, sim_time_us) of a record that fits its key; ValueError otherwise."""
        if isinstance(schema, RecordSchema):
            schema.check(payload)
            seq, sim_time_us = struct.unpack_from("<Qq", payload, 4)
            return seq, sim_time_us
        if schema == "json":
            record = decode_json_record(payload)
            parsed = parse_key(key)
            if parsed is not None and parsed[2] == "status":
                if key not in self.counters.heard:
                    timeline.mark(PROCESS, f"heard {parsed[1]}")
                if record.get("final"):
                    timeline.mark(PROCESS, f"final status of {parsed[1]}")
                self.counters.heard[key] = record
            return record["seq"], record["sim_time_us"]
        if schema == "mavlink":
            if attachment is None or len(attachment) != MIRROR_ATTACHMENT.size:
                raise ValueError("MAVLink mirror frame without its seq/sim-time attachment")
            if not payload or payload[0] != 0xFD:
                raise ValueError("MAVLink mirror frame is not MAVLink 2")
            return MIRROR_ATTACHMENT.unpack(attachment)
        return 0, 0  # outside the contract: kept as opaque bytes

    def _refuse(self, key: str, reason: str) -> None:
        c = self.counters
        c.rejected += 1
        c.rejected_per_key[key] += 1
        c.last_error = f"{key}: {reason}"
        now = time.monotonic()
        if now - self._warned.get(key, -10.0) > 5.0:  # one line per key per 5 s (bounded:
            # only keys under MAX_KEYS get here)
            self._warned[key] = now
            self.log(f"refused a record on {key}: {reason} "
                     f"({c.rejected_per_key[key]} so far on this key)")

    def status(self) -> dict[str, Any]:
        c = self.counters
        return {"name": self.config.name, "records": c.records, "rejected": c.rejected,
                "per_key": dict(c.per_key), "rejected_per_key": dict(c.rejected_per_key),
                "last_error": c.last_error, "heard": c.heard,
                "keys_over_limit": c.keys_over_limit, "inbox_dropped": c.inbox_dropped,
                "write_error": c.write_error, "unwritten": c.unwritten,
                "view_messages": c.view_messages, "view_refused": c.view_refused,
                "file": str(self.files.file.active_path) if self.files.file else None,
                "finished_files": c.files, "usage": self.usage.since_start()}

    # -- the loop ------------------------------------------------------------------------
    def run(self, ready: Callable[[], None] | None = None) -> int:
        if threading.current_thread() is threading.main_thread():
            signal.signal(signal.SIGTERM, self.stop)
            signal.signal(signal.SIGINT, self.stop)  # StopRequest.set: safe in a handler
        session = open_session(self.config.zenoh, exit_on_listen_failure=True)
        timeline.mark(PROCESS, "zenoh session open")
        self.files.start()
        subscribers = [session.declare_subscriber(k, self._on_sample) for k in SUBSCRIBED]
        queryable = session.declare_queryable(logger_key(self.config.name, "status"),
                                              self._on_query)
        token = session.liveliness().declare_token(logger_key(self.config.name))
        if self.drawing is not None:  # records wait in the inbox meanwhile
            warm_up()
        self.log(f"listening on {', '.join(self.config.zenoh.listen) or 'no endpoint'}"
                 f"{'; connecting to ' + ', '.join(self.config.zenoh.connect) if self.config.zenoh.connect else ''}"  # noqa: E501
                 f" ({self.config.zenoh.mode}); logging to {self.config.out_dir}")
        timeline.mark(PROCESS, "ready")
        if ready is not None:
            ready()
        next_flush = time.monotonic() + self.config.flush_period_s
        silence = SilenceWatch(self.log)
        try:
            while not self._stop.is_set():
                wrote = self._drain()
                self._answer_queries()
                now = time.monotonic()
                silence.update(now, wrote)
                if now >= next_flush:
                    self.files.flush()
                    next_flush = now + self.config.flush_period_s
                if not wrote:
                    self._stop.wait(0.005)
        finally:
            token.undeclare()
            for sub in subscribers:
                sub.undeclare()
            queryable.undeclare()
            self._drain()
            self._answer_queries()
            session.close()
            timeline.mark(PROCESS, "zenoh session closed")
            self.files.close()
        return 0

    def _on_query(self, query: zenoh.Query) -> None:
        """A status query, answered by the loop; past MAX_QUERIES waiting, refused here."""
        if self._queries.qsize() >= MAX_QUERIES:
            with contextlib.suppress(zenoh.ZError):
                query.reply_err(b'{"ok": false, "error": "busy"}')
                query.drop()
            return
        self._queries.put(query)

    def _drain(self) -> int:
        return self._inbox.drain(self._write)

    def _answer_queries(self) -> None:
        while True:
            try:
                query = self._queries.get_nowait()
            except queue.Empty:
                return
            try:
                query.reply(query.key_expr, json.dumps(self.status(), default=str).encode())
                query.drop()
            except zenoh.ZError:
                pass


# -- reading logs back ------------------------------------------------------------------
