"""The MAVLink mirror of a log as a .tlog: 8-byte big-endian microseconds, then the
frame, the format MAVExplorer, QGroundControl and pymavlink read."""

from __future__ import annotations

import struct
from pathlib import Path

from contracts.atomic_file import atomic_writer
from ground.record.run_files import iter_messages


def export_tlog(path: Path, out: Path) -> int:
    """The mirror of the log at ``path`` (an .mcap file or a run folder) written to ``out``;
    the number of frames."""
    count = 0
    with atomic_writer(out) as f:
        for _topic, message, data in iter_messages(path, "mavlink/"):
            f.write(struct.pack(">Q", message.log_time // 1000) + data)
            count += 1
    return count
