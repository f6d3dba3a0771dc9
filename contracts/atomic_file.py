"""Files written whole or not at all: every writer of a file another process or a later
run reads (run records, models, logs exported, campaign rows) goes through here.

The content goes to a temporary file of its own beside the file (two writers of one path,
a campaign's client and a worker, never share one), is flushed and fsynced, then renamed
over it: a reader sees the old file or the new one, and a crash or a full disk leaves no
torn file (the temporary one is removed on an error)."""

from __future__ import annotations

import contextlib
import os
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import IO, Any


@contextlib.contextmanager
def atomic_writer(path: Path, text: bool = False, private: bool = False) \
        -> Iterator[IO[Any]]:
    """A file object to write ``path`` through (text: no newline translation, as csv
    wants); it replaces ``path`` when the block ends without an error. Readable by all
    (0644) unless ``private`` (0600: keys)."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with open(fd, "w", newline="", encoding="utf-8") if text else open(fd, "wb") as f:
            yield f
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, 0o600 if private else 0o644)
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(tmp)
        raise


def write_atomic(path: Path, content: str | bytes, private: bool = False) -> None:
    """``path`` holds ``content`` (text or bytes), whole."""
    with atomic_writer(path, text=isinstance(content, str), private=private) as f:
        f.write(content)
