"""The logger's files: numbered MCAP files in one folder (``PREFIX-NNN.mcap``), what a
crash left salvaged at start, a new file past the size or chunk limit, and a disk that
refuses a write: writing stops, what was flushed stays readable, the counters say so."""

from __future__ import annotations

import collections
import re
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from contracts import timeline
from ground.telemetry.mcap_file import ACTIVE_SUFFIX, McapFile, salvage

PROCESS = "logger"  # in the run's timeline


@dataclass
class Counters:
    records: int = 0
    rejected: int = 0
    per_key: dict[str, int] = field(default_factory=lambda: collections.defaultdict(int))
    rejected_per_key: dict[str, int] = field(
        default_factory=lambda: collections.defaultdict(int))
    last_error: str = ""
    keys_over_limit: int = 0  # records refused on a new key past MAX_KEYS (or too long)
    inbox_dropped: int = 0  # puts dropped with the inbox full (the writer behind)
    view_messages: int = 0  # Foxglove messages written beside the records
    view_refused: int = 0  # records whose content the view could not draw (said, skipped)
    write_error: str = ""  # the disk refused a write (full): logging stopped
    unwritten: int = 0  # records that came after it
    files: list[str] = field(default_factory=list)
    heard: dict[str, dict[str, Any]] = field(default_factory=dict)  # status key -> record


class LogFiles:
    def __init__(self, out_dir: Path, prefix: str, chunk_bytes: int, compression: str,
                 rotate_bytes: int, rotate_chunks: int, counters: Counters,
                 log: Callable[[str], None]) -> None:
        self.out_dir, self.prefix = out_dir, prefix
        self.chunk_bytes, self.compression = chunk_bytes, compression
        self.rotate_bytes, self.rotate_chunks = rotate_bytes, rotate_chunks
        self.counters = counters
        self.log = log
        self.file: McapFile | None = None
        self._index = 0
        self._flushed_records = 0  # counters.records at the last flush that worked
        self._flushed_per_key: dict[str, int] = {}  # and counters.per_key

    def start(self) -> None:
        """Salvage what a crash left, then open the next numbered file."""
        out = self.out_dir
        out.mkdir(parents=True, exist_ok=True)
        for active in sorted(out.glob(f"*{ACTIVE_SUFFIX}")):
            salvage(active, self.log)
        taken = [int(m.group(1)) for p in out.glob(f"{self.prefix}-*.mcap")
                 if (m := re.match(rf"{re.escape(self.prefix)}-(\d+)", p.name))]
        self._index = max(taken, default=-1) + 1
        self._open_next()

    def _open_next(self) -> None:
        path = self.out_dir / f"{self.prefix}-{self._index:03d}.mcap"
        self._index += 1
        self.file = McapFile(path, self.chunk_bytes, self.compression)
        self.log(f"writing {path.name}")

    def flush(self) -> None:
        """Close the open chunk; start the next file past the size or chunk limit."""
        if self.counters.write_error:
            return
        try:
            self.file.flush()
            self._flushed_records = self.counters.records
            self._flushed_per_key = dict(self.counters.per_key)  # at most MAX_KEYS
            if (self.file.size >= self.rotate_bytes
                    or self.file.chunks >= self.rotate_chunks):
                self._rotate()
        except OSError as exc:
            self.write_failed(exc)

    def write_failed(self, exc: OSError) -> None:
        """A full disk (or a file size limit): stop writing, keep what was flushed, say
        so; the loop goes on answering status queries, which report it."""
        c = self.counters
        # The records since the last flush were in the chunk the disk refused.
        c.unwritten += c.records - self._flushed_records
        c.records = self._flushed_records
        c.per_key.clear()
        c.per_key.update(self._flushed_per_key)
        c.write_error = f"{exc.strerror or exc} ({self.file.active_path.name})"
        c.last_error = f"logging stopped: {c.write_error}"
        self.file.abandon()
        self.log(f"cannot write {self.file.active_path}: {exc.strerror or exc}: logging "
                 f"stopped after {c.records} records; the file keeps the "
                 f"{self.file.flushed_bytes} bytes flushed before (readable: ivfm report "
                 "and the next logger salvage it)")

    def _rotate(self) -> None:
        done = self.file.finish()
        self.counters.files.append(str(done))
        self._open_next()

    def close(self) -> None:
        """Finish the open file; after a refused write, leave it as the disk allowed."""
        if not self.counters.write_error:
            try:
                done = self.file.finish()
                timeline.mark(PROCESS, "file closed")
                self.counters.files.append(str(done))
                self.log(f"finished {done.name}: {self.counters.records} records, "
                         f"{self.counters.rejected} refused")
                return
            except OSError as exc:  # the summary did not fit
                self.write_failed(exc)
        self.log(f"left {self.file.active_path.name} as the disk allowed: "
                 f"{self.counters.records} records written, {self.counters.unwritten} not")
