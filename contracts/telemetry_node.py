"""A vehicle process's side of Zenoh (docs/architecture.md): its publishers, the batches
its records travel in, the requests it serves, its liveliness and its status.

A node never blocks its process's control loop: publications use Zenoh's drop-on-
congestion, a failed put is counted and not raised, and requests (perturbations, start)
are queued by the Zenoh thread and taken by the loop when it is ready. CDR records and
mirror frames wait in a batch and go as one put per span of sim time
(``ZenohOptions.batch_s``; contracts/telemetry.py: pack_batch), sooner when the batch
is full or a span of wall time old; JSON records go on their own, after the batch.
"""

from __future__ import annotations

import json
import queue
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import zenoh

from contracts import timeline
from contracts.realtime import ProcessUsage
from contracts.telemetry import (
    BATCH_TOPIC,
    MIRROR_ATTACHMENT,
    RecordSchema,
    json_record,
    mavlink_key,
    pack_batch,
    schema_for_key,
    vehicle_key,
)
from contracts.zenoh_link import ZenohOptions, open_session

STATUS_PERIOD_S = 1.0
BATCH_MAX_RECORDS = 256  # a batch goes when it holds this many, whatever its span
PERTURBATIONS_OFF = ("perturbations are off on this vehicle: start its processes with "
                     "--perturbations (scenario runs do) to take them")


class Publisher:
    """One key: counts what it published, never raises into the caller's loop. With a
    ``batch`` its records go into it, for the node to send per span of sim time (and
    ``flush`` at once when the batch is full); without, ``flush`` (the node's) runs
    before each put, so a record sent on its own follows the records put before it."""

    def __init__(self, session: zenoh.Session | None, key: str,
                 batch: TelemetryBatch | None = None,
                 flush: Callable[[], None] | None = None) -> None:
        self.key = key
        self.count = 0
        self.failed = 0
        self._pub = None
        self._batch = batch
        self._flush = flush
        if session is not None and batch is None:
            self._pub = session.declare_publisher(
                key, congestion_control=zenoh.CongestionControl.DROP)

    @property
    def matched(self) -> bool:
        return self._pub is not None and self._pub.matching_status.matching

    def put(self, payload: bytes, attachment: bytes | None = None) -> None:
        if self._batch is not None:
            self.count += 1
            if self._batch.add(self.key, payload, attachment) >= BATCH_MAX_RECORDS and \
                    self._flush is not None:
                self._flush()
            return
        if self._pub is None:
            return
        if self._flush is not None:
            self._flush()
        try:
            if attachment is None:
                self._pub.put(payload)
            else:
                self._pub.put(payload, attachment=attachment)
            self.count += 1
        except zenoh.ZError:
            self.failed += 1


class TelemetryBatch:
    """Records waiting for their batch: keys, payloads and attachments in order, packed
    into one put by ``take`` (contracts/telemetry.py: pack_batch)."""

    def __init__(self) -> None:
        self._keys: dict[str, int] = {}
        self._index: list[int] = []
        self._payloads: list[bytes] = []
        self._attachments: list[bytes] = []
        self.since_s = 0.0  # when the oldest record came (time.monotonic)

    def __len__(self) -> int:
        return len(self._payloads)

    def add(self, key: str, payload: bytes, attachment: bytes | None) -> int:
        """A record into the batch; how many it holds now."""
        if not self._payloads:
            self.since_s = time.monotonic()
        index = self._keys.get(key)
        if index is None:
            index = self._keys[key] = len(self._keys)
        self._index.append(index)
        self._payloads.append(payload)
        self._attachments.append(attachment or b"")
        return len(self._payloads)

    def take(self) -> bytes:
        """The batch of the records waiting (there must be some); empties it."""
        batch = pack_batch(list(self._keys), self._index, self._payloads, self._attachments)
        self._keys, self._index, self._payloads, self._attachments = {}, [], [], []
        return batch

@dataclass
class Request:
    """A query taken off the Zenoh thread; the loop answers it with ``reply``."""

    topic: str
    data: Any
    _query: Any
    answered: threading.Event = field(default_factory=threading.Event)

    def reply(self, ok: bool, **body: Any) -> None:
        payload = json.dumps({"ok": ok, **body}, allow_nan=False, default=str).encode()
        try:
            if ok:
                self._query.reply(self._query.key_expr, payload)
            else:
                self._query.reply_err(payload)
            self._query.drop()
        except zenoh.ZError:
            pass  # the asker has gone: nothing to tell
        self.answered.set()

    def refuse(self, exc: Exception, log: Callable[[str], None]) -> None:
        """Refuse with the reason: a ValueError's message (bad input), or any other
        exception as an internal error, so that a defect in a handler refuses one request
        instead of ending the process's loop. Said in the process's log too."""
        if isinstance(exc, ValueError):
            log(f"refused {self.topic} request: {exc}")
            self.reply(False, error=str(exc))
        else:
            log(f"refused {self.topic} request on an internal error: {exc!r}")
            self.reply(False, error=f"internal error: {type(exc).__name__}")


# Bounds on what askers can queue in a vehicle process (the loop answers a few per step).
MAX_REQUEST_BYTES = 64 * 1024
MAX_PENDING_REQUESTS = 64


class TelemetryNode:
    """A vehicle process's Zenoh side: publishers, liveliness, request queues, status."""

    def __init__(self, options: ZenohOptions, vehicle: int, process: str,
                 log: Callable[[str], None] | None = None) -> None:
        self.vehicle = vehicle
        self.process = process
        self.log = log or (lambda text: print(f"{process}: {text}", file=sys.stderr))
        self.session = open_session(options) if options.enabled else None
        timeline.mark(process, "zenoh session open")
        self.token = None
        if self.session is not None:
            self.token = self.session.liveliness().declare_token(vehicle_key(vehicle, process))
        self.publishers: dict[str, Publisher] = {}
        self._mirror: dict[tuple[int, int, str], Publisher] = {}  # by (sysid, compid, name)
        # Batches: CDR records and mirror frames, one put per span of sim time.
        self.batch_span_us = round(options.batch_s * 1e6)
        self.batch_span_s = options.batch_s
        self._batch = (TelemetryBatch() if self.session is not None and self.batch_span_us
                       else None)
        self._batch_pub = Publisher(self.session if self._batch is not None else None,
                                    vehicle_key(vehicle, process, BATCH_TOPIC))
        self._batch_due_us = 0
        self.requests: queue.SimpleQueue[Request] = queue.SimpleQueue()
        self._queryables: list[Any] = []
        self._status = self.publisher("status")
        self._status_due_s = 0.0
        self.mirror_seq = 0
        self.usage = ProcessUsage()  # the run's CPU and switches, in the final status

    @property
    def enabled(self) -> bool:
        return self.session is not None

    def publisher(self, topic: str) -> Publisher:
        """The publisher of ``topic``: batched if it carries CDR records, else on its own
        key after the batch waiting."""
        key = vehicle_key(self.vehicle, self.process, topic)
        batched = isinstance(schema_for_key(key), RecordSchema)
        pub = self.publishers[topic] = self._publisher(key, batched)
        return pub

    def _publisher(self, key: str, batched: bool) -> Publisher:
        if self._batch is None:
            return Publisher(self.session, key)
        return Publisher(self.session, key, self._batch if batched else None, self.flush)

    def end_step(self, sim_time_us: int) -> None:
        """After a step's records: the batch goes once its span of sim time is over."""
        if self._batch is not None and sim_time_us >= self._batch_due_us:
            span = self.batch_span_us
            self._batch_due_us = sim_time_us - sim_time_us % span + span
            self.flush()

    def flush(self) -> None:
        """The records waiting, in one put now."""
        if self._batch:
            self._batch_pub.put(self._batch.take())

    def flush_stale(self, now_s: float | None = None) -> None:
        """While sim time stands still (or steps come slowly): records wait at most a span
        of wall time too (``now_s``: time.monotonic, or now)."""
        if self._batch and (time.monotonic() if now_s is None else now_s) \
                - self._batch.since_s >= self.batch_span_s:
            self.flush()

    def serve(self, topic: str, refuse: str | None = None) -> None:
        """Accept queries on ``topic``: JSON payloads go to ``requests``; a payload that is
        not JSON is refused here, on the Zenoh thread. ``refuse``: a service that is off
        answers every query with this error."""
        if self.session is None:
            return

        def on_query(query: zenoh.Query) -> None:
            if refuse is not None:
                Request(topic, None, query).reply(False, error=refuse)
                return
            raw = query.payload.to_bytes() if query.payload is not None else b""
            if len(raw) > MAX_REQUEST_BYTES:
                Request(topic, None, query).reply(
                    False, error=f"payload of {len(raw)} bytes is over {MAX_REQUEST_BYTES}")
                return
            if self.requests.qsize() >= MAX_PENDING_REQUESTS:
                Request(topic, None, query).reply(
                    False, error=f"busy: {MAX_PENDING_REQUESTS} requests are waiting")
                return
            try:
                data = json.loads(raw) if raw else {}
            except (ValueError, UnicodeDecodeError) as exc:
                Request(topic, None, query).reply(False, error=f"payload is not JSON: {exc}")
                return
            self.requests.put(Request(topic, data, query))

        self._queryables.append(self.session.declare_queryable(
            vehicle_key(self.vehicle, self.process, topic), on_query))

    def mirror(self, sysid: int, compid: int, message_name: str, frame: bytes,
               sim_time_us: int) -> None:
        """A MAVLink frame onto ``mavlink/sysid/compid/NAME`` (sim time in the attachment)."""
        if self.session is None:
            return
        pub = self.mirror_publisher(sysid, compid, message_name)
        pub.put(frame, MIRROR_ATTACHMENT.pack(self.mirror_seq, sim_time_us))
        self.mirror_seq += 1

    def mirror_publisher(self, sysid: int, compid: int, message_name: str) -> Publisher:
        """The publisher of a mirror key (declared on first use, or ahead of a loop)."""
        pub = self._mirror.get((sysid, compid, message_name))
        if pub is None:
            pub = self._mirror[sysid, compid, message_name] = self._publisher(
                mavlink_key(sysid, compid, message_name), batched=True)
        return pub

    def counts(self) -> dict[str, int]:
        out = {pub.key: pub.count for pub in self.publishers.values() if pub is not self._status}
        out.update({pub.key: pub.count for pub in self._mirror.values()})
        return out

    def status(self, sim_time_us: int, final: bool = False, force: bool = False,
               **extra: Any) -> None:
        """Counters at most once a second of wall time (always when final or forced)."""
        self.flush_stale()
        if not self.status_due(final or force):
            return
        now = time.monotonic()
        self._status_due_s = now + STATUS_PERIOD_S
        failed = sum(p.failed for p in [*self.publishers.values(), *self._mirror.values()])
        if final:
            extra["usage"] = self.usage.since_start()
        self._status.put(json_record(self._status.count, sim_time_us, process=self.process,
                                     vehicle=self.vehicle, final=final,
                                     published=self.counts(), failed_puts=failed,
                                     batches=self._batch_pub.count, **extra))

    def status_due(self, final: bool = False) -> bool:
        """Whether ``status`` would publish now: callers skip gathering its fields."""
        return self.session is not None and (final or time.monotonic() >= self._status_due_s)

    def close(self) -> None:
        if self.session is None:
            return
        self.flush()
        try:
            if self.token is not None:
                self.token.undeclare()
            self.session.close()
        except zenoh.ZError as exc:
            self.log(f"zenoh session close: {exc}")
        self.session = None
        timeline.mark(self.process, "zenoh session closed")
