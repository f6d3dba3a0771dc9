"""One MCAP file of the logger being written (channels by key, time-bounded chunks, a
whole prefix on disk after every flush), and the salvage of one a crash left unfinished
(``NAME.mcap.active``: every complete record copied into a finished file).

A message goes into the open chunk by ``McapFile.add``, which writes what the mcap
writer's ``add_message`` writes (the same bytes: tests/ground/test_logger_files.py
writes a file both ways and compares) in one ``struct`` call instead of some twenty
Python calls: the writer's own path was a fifth of the logger's CPU (8 us a message,
six hundred messages a simulated second). It keeps the writer's bookkeeping (the chunk's
message index and times, the file's statistics) in the writer's own objects, so the
writer closes chunks and writes the summary as ever; like the flush, it relies on the
writer's private state, which pyproject.toml pins to the 1.6 series."""

from __future__ import annotations

import contextlib
import itertools
import json
import os
import struct
from collections.abc import Callable
from pathlib import Path

from mcap.data_stream import RecordBuilder
from mcap.opcode import Opcode
from mcap.records import Channel, Message, MessageIndex, Schema
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer

from contracts.telemetry import JSON_RECORD_SCHEMA, RecordSchema
from ground.telemetry.foxglove_scene import channel_json_schema
from ground.telemetry.foxglove_view import Output

ACTIVE_SUFFIX = ".mcap.active"
# An MCAP Message record's head: opcode, record length, channel id, sequence, log time,
# publish time; the length counts the 22 bytes after it and the data.
_MESSAGE_HEAD = struct.Struct("<BQHIQQ")
_MESSAGE_FIXED = 22


class _MessageIndex(MessageIndex):
    """One channel's index in a chunk, written as the writer writes it (opcode, length,
    channel id, byte count, then log time and offset per message) in one ``struct`` call:
    the writer's own loop made two calls a message, 1 ms of CPU a simulated second."""

    def write(self, stream: RecordBuilder) -> None:
        n = len(self.records)
        stream.write(struct.pack(f"<BQHI{2 * n}Q", Opcode.MESSAGE_INDEX, 6 + 16 * n,
                                 self.channel_id, 16 * n,
                                 *itertools.chain.from_iterable(self.records)))


class McapFile:
    """One MCAP file being written: channels by key, time-bounded chunks."""

    def __init__(self, path: Path, chunk_bytes: int, compression: str) -> None:
        self.active_path = path.with_name(path.name + ".active")
        self.path = path
        self.stream = open(self.active_path, "wb")  # noqa: SIM115 (closed in finish)
        compression = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4,
                       "none": CompressionType.NONE}[compression]
        self.writer = Writer(self.stream, chunk_size=chunk_bytes, compression=compression)
        self.writer.start(profile="", library="ivfm-sitl ground logger")
        self.schemas: dict[str, int] = {}
        self.channels: dict[str, int] = {}
        self.dirty = False
        self.flushed_bytes = 0  # the file up to here is whole (a crash keeps it)
        self._chunk = self.writer._Writer__chunk_builder  # noqa: SLF001 (module docstring)
        self._statistics = self.writer._Writer__statistics  # noqa: SLF001
        self._chunk_bytes = chunk_bytes

    def channel(self, key: str, schema: RecordSchema | str | None) -> int:
        channel_id = self.channels.get(key)
        if channel_id is not None:
            return channel_id
        if isinstance(schema, RecordSchema):
            schema_id = self._schema(schema.name, "ros2msg", schema.ros2msg.encode())
            encoding = "cdr"
        elif schema == "json":
            schema_id = self._schema("ivfm.JsonRecord", "jsonschema", JSON_RECORD_SCHEMA)
            encoding = "json"
        elif schema == "mavlink":
            schema_id, encoding = 0, "mavlink"
        else:
            schema_id, encoding = 0, "application/octet-stream"
        channel_id = self.writer.register_channel(key, encoding, schema_id)
        self.channels[key] = channel_id
        return channel_id

    def view_channel(self, output: Output) -> int:
        """The channel of a Foxglove topic: protobuf with Foxglove's schema, or JSON with
        a schema naming the record's fields."""
        channel_id = self.channels.get(output.topic)
        if channel_id is not None:
            return channel_id
        message = output.message
        fields = channel_json_schema(message)
        if fields is not None:
            schema_id = self._schema(f"ivfm.view{output.topic.replace('/', '.')}",
                                     "jsonschema", json.dumps(fields).encode())
            encoding = "json"
        else:
            schema = type(message).get_schema()
            schema_id = self._schema(schema.name, schema.encoding, bytes(schema.data))
            encoding = schema.encoding
        channel_id = self.writer.register_channel(output.topic, encoding, schema_id)
        self.channels[output.topic] = channel_id
        return channel_id

    def _schema(self, name: str, encoding: str, data: bytes) -> int:
        if name not in self.schemas:
            self.schemas[name] = self.writer.register_schema(name, encoding, data)
        return self.schemas[name]

    def add(self, channel_id: int, log_time_ns: int, sim_time_ns: int, seq: int,
            data: bytes) -> None:
        """The writer's ``add_message(channel_id, log_time_ns, data, sim_time_ns, seq)``
        (the sequence cut to MCAP's 32 bits), on the writer's own state."""
        chunk, statistics = self._chunk, self._statistics
        buffer = chunk.record_writer._buffer  # noqa: SLF001 (a new one after each chunk)
        index = chunk.message_indices.get(channel_id)
        if index is None:
            index = chunk.message_indices[channel_id] = _MessageIndex(channel_id, [])
        index.records.append((log_time_ns, buffer.tell()))
        buffer.write(_MESSAGE_HEAD.pack(Opcode.MESSAGE, _MESSAGE_FIXED + len(data),
                                        channel_id, seq & 0xFFFFFFFF, log_time_ns,
                                        sim_time_ns))
        buffer.write(data)
        if chunk.num_messages == 0:
            chunk.message_start_time = chunk.message_end_time = log_time_ns
        elif log_time_ns < chunk.message_start_time:
            chunk.message_start_time = log_time_ns
        elif log_time_ns > chunk.message_end_time:
            chunk.message_end_time = log_time_ns
        chunk.num_messages += 1
        if statistics.message_count == 0 or log_time_ns < statistics.message_start_time:
            statistics.message_start_time = log_time_ns
        if log_time_ns > statistics.message_end_time:
            statistics.message_end_time = log_time_ns
        statistics.channel_message_counts[channel_id] += 1
        statistics.message_count += 1
        self.dirty = True
        if buffer.tell() > self._chunk_bytes:
            self.writer._Writer__finalize_chunk()  # noqa: SLF001 (as its add_message)

    def flush(self) -> None:
        """Close the open chunk and push it to the OS: a crash after this loses nothing
        written so far. (The mcap writer has no public call for it; its own end of chunk
        is what we ask for.)"""
        if self.dirty:
            self.writer._Writer__finalize_chunk()  # noqa: SLF001
            self.writer._Writer__flush()  # noqa: SLF001
            self.stream.flush()
            self.dirty = False
            self.flushed_bytes = self.stream.tell()

    def abandon(self) -> None:
        """The disk refused a write: keep the file as its last flush left it (a whole
        prefix, read as a killed logger's is) and write nothing more to it."""
        with contextlib.suppress(OSError):
            os.ftruncate(self.stream.fileno(), self.flushed_bytes)
        with contextlib.suppress(OSError):
            self.stream.close()  # may try its buffer once more
        with contextlib.suppress(OSError):
            os.truncate(self.active_path, self.flushed_bytes)

    @property
    def size(self) -> int:
        return self.stream.tell()

    @property
    def chunks(self) -> int:
        """Chunks written so far (each holds an index entry in memory until finish)."""
        return len(self.writer._Writer__chunk_indices)  # noqa: SLF001

    def finish(self) -> Path:
        self.writer.finish()
        self.stream.close()
        self.active_path.replace(self.path)
        return self.path


def salvage(active_path: Path, log: Callable[[str], None] = print) -> Path:
    """Copy every complete record of an unfinished MCAP file into a finished one."""
    final = active_path.with_name(active_path.name[:-len(".active")])
    if final.exists():
        final = final.with_name(final.stem + "-salvaged.mcap")
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    count = 0
    with open(active_path, "rb") as src, open(final, "wb") as dst:
        writer = Writer(dst)
        writer.start(profile="", library="ivfm-sitl ground logger (salvaged)")
        schema_ids: dict[int, int] = {}
        channel_ids: dict[int, int] = {}
        try:
            for record in StreamReader(src, validate_crcs=False).records:
                if isinstance(record, Schema) and record.id not in schemas:
                    schemas[record.id] = record
                    schema_ids[record.id] = writer.register_schema(
                        record.name, record.encoding, record.data)
                elif isinstance(record, Channel) and record.id not in channels:
                    channels[record.id] = record
                    channel_ids[record.id] = writer.register_channel(
                        record.topic, record.message_encoding,
                        schema_ids.get(record.schema_id, 0), record.metadata)
                elif isinstance(record, Message) and record.channel_id in channel_ids:
                    writer.add_message(channel_ids[record.channel_id], record.log_time,
                                       record.data, record.publish_time, record.sequence)
                    count += 1
        except Exception as exc:  # noqa: BLE001 (a torn file fails in many ways: a cut
            # record, a chunk that does not decompress); what came before it is kept
            log(f"salvage of {active_path.name} stopped at a torn record: "
                f"{type(exc).__name__}: {exc}")
        writer.finish()
    active_path.unlink()
    log(f"salvaged {count} records from {active_path.name} into {final.name}")
    return final
